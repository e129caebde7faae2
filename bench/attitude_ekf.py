"""Time the attitude EKF's hand-written 3×3 algebra against the same filter on kalman.py.

Run from the repository root: ``.venv/bin/python -m bench.attitude_ekf [trace.txt.xz]``.
One batch over the whole trace's gyro and accelerometer, best of 7 runs (``timeit``), for
``server.positioning.motion.attitude_ekf.attitude_ekf`` and for the reference
``generic_attitude_ekf`` of its tests (``kalman.predict_ekf`` and ``kalman.update``);
the largest difference of their outputs is printed too.
"""

from __future__ import annotations

import sys
import timeit
from pathlib import Path

import numpy as np

from lab.datasets.ilc import read_trace
from server.positioning.motion.attitude_ekf import AttitudeParams, attitude_ekf, initial_attitude
from tests.support.attitude_reference import generic_attitude_ekf

TRACE = Path("../shared/data/ilc20-sample/site2/F1/path_data_files/5dd365f944333f00067aa11a.txt.xz")


def main() -> None:
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else TRACE
    trace = read_trace(path)
    gyro, accel = trace.gyro, trace.accel
    params = AttitudeParams()
    span_s = (gyro[-1, 0] - gyro[0, 0]) / 1000.0
    sys.stdout.write(f"{path}: {len(gyro)} gyro, {len(accel)} accel samples, {span_s:.0f} s\n")
    outputs = []
    per_sample = []
    for name, ekf in (("matrix3", attitude_ekf), ("kalman.py", generic_attitude_ekf)):
        outputs.append(ekf(initial_attitude(params), gyro, accel, params)[1])
        best_s = min(
            timeit.repeat(
                lambda ekf=ekf: ekf(initial_attitude(params), gyro, accel, params),
                number=1,
                repeat=7,
            )
        )
        per_sample.append(best_s / len(gyro) * 1e6)
        sys.stdout.write(f"{name:>10}: {best_s * 1e3:7.1f} ms, {per_sample[-1]:5.1f} µs/sample\n")
    difference = float(np.max(np.abs(outputs[0] - outputs[1])))
    sys.stdout.write(f"kalman.py / matrix3: {per_sample[1] / per_sample[0]:.1f}x; ")
    sys.stdout.write(f"largest output difference {difference:.1e} rad\n")


if __name__ == "__main__":
    main()
