"""Draw the front page's picture with carfeel itself: `python docs/scripts/front_picture.py`.

One push into first gear and back with the shipped paper-first-gear preset (seed 0), as
`carfeel simulate shift --pull-out --plot` draws it: force and position against time, the
stages coloured, and force against position (the paper's Fig. 5, 6, 9 and 11).
"""

import tempfile
from pathlib import Path

from carfeel.runs import ShiftRun, run_shift

OUT = Path(__file__).resolve().parents[1] / "assets" / "shift.png"

with tempfile.TemporaryDirectory() as folder:
    run_shift(ShiftRun(seed=0, pull_out=True), Path(folder) / "shift.csv", OUT)
print(f"wrote {OUT}")
