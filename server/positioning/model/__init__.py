"""What every part of the core speaks: the events an engine reads and the fix it gives
(``events``), engine parameters (``params``), a recorded walk (``walk``), engine states as
arrays (``state_codec``), the uncertainty radii of a fix (``accuracy``), where a building
sits on the Earth (``geo``) and the error statistics a fix is judged by
(``error_metrics``). It imports nothing else of the core."""
