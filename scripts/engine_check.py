"""What the scripts that check evpose's readers against other engines share
(`third-party-formats.py`, `evt21-engines.py`): evpose's read of a file, the comparison of two
event arrays, and the tally of failures."""
import pathlib
import subprocess
import tempfile

import numpy as np

REPO = pathlib.Path(__file__).resolve().parent.parent
STREET = REPO.parent / "shared" / "recordings" / "davis346-street.aedat4"

failures = []


def report(name, ok, detail=""):
    print(f"{'ok  ' if ok else 'FAIL'} {name}{': ' + detail if detail else ''}")
    if not ok:
        failures.append(name)


def evpose_read(evpose, path, *extra):
    """The events `evpose convert` reads from `path`, as an int64 (N, 4) [x, y, t_us, p] array
    (None and the last line of its error, the cause, where it fails)."""
    with tempfile.TemporaryDirectory() as d:
        out = pathlib.Path(d) / "e.npy"
        r = subprocess.run([evpose, "convert", str(path), "--out", str(out), *extra],
                           capture_output=True, text=True)
        if r.returncode != 0:
            return None, r.stderr.strip().splitlines()[-1].strip()
        return np.load(out).astype(np.int64), ""


def compare(name, got, want, why=""):
    if got is None:
        report(name, False, why)
    elif got.shape != want.shape:
        report(name, False, f"{len(got)} events against {len(want)}")
    else:
        bad = np.nonzero((got != want).any(axis=1))[0]
        report(name, len(bad) == 0, f"{len(got)} events" if len(bad) == 0 else
               f"{len(bad)} differ, first at {bad[0]}: {got[bad[0]]} against {want[bad[0]]}")
