"""Motion from the phone's own sensors: steps (``pdr``, ``step_tracker``), turns and straight
stretches (``turns``, ``straight_lines``), attitude and heading (``attitude_ekf``,
``heading_fusion``, ``sensor_geometry``, ``matrix3``, ``sensor_streams``), floor changes
(``barometer``) and a recorded walk's steps (``walk_steps``).

Frames and units. Phone axes are Android's (x to the right edge, y to the top edge, z out
of the screen); the world frame is east-north-up. The accelerometer gives specific force
in m/s² with gravity included (a phone lying flat screen up reads about ``[0, 0, +g]``),
the gyroscope rad/s right-handed about each phone axis, the magnetometer µT. A *heading*
is in radians, clockwise from north, wrapped to (-pi, pi]; unless said otherwise it is the
heading of the phone's top edge (y axis) projected on the horizontal plane. Samples are
``(n, 4)`` arrays ``[t_ms, x, y, z]`` with strictly increasing ``t_ms``.
"""
