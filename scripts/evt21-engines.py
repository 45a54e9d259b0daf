#!/usr/bin/env python3
"""evpose's EVT 2.1 reading and writing against independent engines, in both byte orders: evutils (reads and
writes the IMX636's order, OpenEB's `legacy`: each 64-bit word's upper half first) and evlib
(reads the GenX320's order: each word little-endian as a whole). faery 0.7.1 and expelliarmus
1.1.12 have no EVT 2.1, and no public repository holds a real EVT 2.1 recording, so:

1. evutils writes the street recording (`../shared/recordings/davis346-street.aedat4`, read by
   `evpose convert`, times from 0) as EVT 2.1; evpose and evutils read it back; the events must
   equal the ones written, exactly. The same words with their halves swapped (and the header's
   endianness changed: this script's only edit) are the GenX320's order: evpose and evlib read
   them.
   evpose writes the street recording in both orders (`convert --encoding evt21|evt21-legacy`):
   evutils reads the legacy file, evlib the other, and evpose both, as the events given.
2. A stream built here word by word from the format's description (time highs, vectors of
   random 32-bit masks at columns aligned to 32 or not, triggers, OTHERS words, a wrap of the
   28-bit time-high counter), in both byte orders: evutils decodes the legacy file, evlib the
   little-endian one, and evpose both; all must agree.
3. `--write-fixtures DIR`: the files `host/tests/third_party.rs` reads: evutils's EVT 2.1 of
   2,000 street events, the same words in the GenX320's order, and 300 words of the stream of
   (2) in both orders, each with the events the engines read from it (`*.npy`, [x, y, t, p]).

4. `--firmware-asset PATH`: the street recording's first 7,500 events as EVT 2.1 words in the
   GenX320's order (the header cut off): evutils's words, halves swapped, which evlib reads as
   the events given; the firmware's boot check of the core's EVT 2.1 decoding
   (`firmware/assets/street-00.evt21`).

usage: python3 -m venv /tmp/ev21 && /tmp/ev21/bin/pip install evutils==0.3.18 evlib==0.13.2 \\
           polars==2.2.0
       /tmp/ev21/bin/python scripts/evt21-engines.py [--evpose target/release/evpose] \\
           [--write-fixtures DIR] [--firmware-asset PATH]
Exit status 1 when any comparison fails.
"""
import argparse
import pathlib
import random
import subprocess
import sys
import tempfile

import evlib
import numpy as np
import polars as pl
from evutils.io import EventReader, EventWriter

from engine_check import REPO, STREET, compare, evpose_read, failures


def rows(x, y, t, p):
    return np.stack([np.asarray(v, np.int64) for v in (x, y, t, p)], axis=1)


def evutils_read(path):
    ev = EventReader(str(path)).read_all()
    ev = ev[0] if isinstance(ev, tuple) else ev
    a = ev.to_aos() if hasattr(ev, "to_aos") else ev
    return rows(a["x"], a["y"], a["t"], a["p"])


def evlib_read(path):
    df = evlib.load_events(str(path), sort=False).collect()
    df = df.with_columns(pl.col("t").dt.total_microseconds())
    return rows(df["x"], df["y"], df["t"], (df["polarity"].to_numpy() > 0).astype(np.int64))


def split(path):
    """(header lines, body) of a RAW file."""
    data = path.read_bytes()
    pos = 0
    while data.startswith(b"%", pos):
        pos = data.index(b"\n", pos) + 1
        if data[:pos].endswith(b"% end\n"):
            break
    return data[:pos], data[pos:]


def to_little(legacy, out):
    """The words of a legacy-order file in the GenX320's order (halves swapped), its header
    saying so."""
    head, body = split(legacy)
    w = np.frombuffer(body, "<u4").reshape(-1, 2)[:, ::-1].copy()
    lines = ["% endianness little\n" if l.lower().startswith("% endianness") else
             l.replace("endianness=legacy", "endianness=little")
             for l in head.decode().splitlines(keepends=True)]
    out.write_bytes("".join(lines).encode() + w.tobytes())


def evutils_write(ev, size, path):
    a = np.zeros(len(ev), dtype=[("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    a["x"], a["y"], a["p"], a["t"] = ev[:, 0], ev[:, 1], ev[:, 3], ev[:, 2]
    w = EventWriter(str(path), width=size[0], height=size[1], format="evt21")
    w.write(a)
    if hasattr(w, "close"):
        w.close()


def built_stream(seed, n):
    """EVT 2.1 words (upper half, mask) from the format's description: a time high whenever
    t >> 6 changes (the 28-bit counter wraps once, from its largest value to 0), vectors of
    random masks, 1 % triggers and 1 % OTHERS words."""
    rng = random.Random(seed)
    words, last = [], None
    t = ((1 << 28) - 8) << 6  # eight periods before the wrap
    for _ in range(n):
        t += rng.randint(0, 40)
        if t >> 6 != last:
            last = t >> 6
            words.append((0x8 << 28 | (last & 0x0FFFFFFF), 0))
        r = rng.random()
        if r < 0.01:
            words.append((0xA << 28 | (t & 63) << 22 | rng.randint(0, 31) << 8 | 1, 0))
            continue
        if r < 0.02:
            words.append((0xE << 28 | (t & 63) << 22 | 0x14, rng.getrandbits(22)))
            continue
        x = rng.randint(0, 1248)
        x = x & ~31 if rng.random() < 0.7 else x
        mask = rng.getrandbits(32) if rng.random() < 0.5 else 1 << rng.randint(0, 31)
        words.append((rng.randint(0, 1) << 28 | (t & 63) << 22 | x << 11 | rng.randint(0, 719),
                      mask))
    return words


def write_words(words, path, legacy):
    order = "legacy" if legacy else "little"
    head = (f"% format EVT21;height=720;width=1280;endianness={order}\n% endianness {order}\n"
            "% evt 2.1\n% geometry 1280x720\n% end\n").encode()
    w = np.array([(u, m) if legacy else (m, u) for u, m in words], "<u4")
    path.write_bytes(head + w.tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--evpose", default=str(REPO / "target" / "release" / "evpose"))
    ap.add_argument("--write-fixtures", type=pathlib.Path)
    ap.add_argument("--firmware-asset", type=pathlib.Path)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = pathlib.Path(d)
        street, why = evpose_read(a.evpose, STREET)
        if street is None:
            sys.exit(f"evpose cannot read {STREET}: {why}")
        street[:, 2] -= street[0, 2]
        print(f"street recording: {len(street)} events")

        legacy = d / "street.evutils-evt21.raw"
        evutils_write(street, (346, 260), legacy)
        little = d / "street.evt21-little.raw"
        to_little(legacy, little)
        got, why = evpose_read(a.evpose, legacy)
        compare("evutils writes, evpose reads (legacy)", got, street, why)
        compare("evutils writes, evutils reads (legacy)", evutils_read(legacy), street)
        got, why = evpose_read(a.evpose, little)
        compare("halves swapped, evpose reads (little)", got, street, why)
        compare("halves swapped, evlib reads (little)", evlib_read(little), street)

        # evpose's EVT 2.1 writer (`convert --out F.raw --encoding evt21|evt21-legacy`): the
        # engine of each byte order reads the street events back (times from the first).
        src = d / "street.npy"
        np.save(src, street.astype(np.float64))
        for enc, read in [("evt21-legacy", evutils_read), ("evt21", evlib_read)]:
            out = d / f"street.evpose-{enc}.raw"
            subprocess.run([a.evpose, "convert", str(src), "--width", "346", "--height", "260",
                            "--out", str(out), "--encoding", enc], check=True,
                           capture_output=True)
            got = read(out)
            got[:, 2] -= got[0, 2]
            name = "evutils" if read is evutils_read else "evlib"
            compare(f"evpose writes ({enc}), {name} reads", got, street)
            back, why = evpose_read(a.evpose, out)
            if back is not None:
                back[:, 2] -= back[0, 2]
            compare(f"evpose writes ({enc}), evpose reads", back, street, why)

        words = built_stream(1, 20_000)
        built = {o: d / f"built.{o}.raw" for o in ("legacy", "little")}
        write_words(words, built["legacy"], True)
        write_words(words, built["little"], False)
        want = evutils_read(built["legacy"])
        print(f"built stream: {len(words)} words, {len(want)} events (evutils)")
        compare("built stream: evlib (little) against evutils (legacy)",
                evlib_read(built["little"]), want)
        for o, path in built.items():
            got, why = evpose_read(a.evpose, path)
            compare(f"built stream: evpose ({o}) against evutils", got, want, why)

        if a.write_fixtures:
            out = a.write_fixtures
            out.mkdir(parents=True, exist_ok=True)
            small = street[:2000]
            evutils_write(small, (346, 260), out / "street.evutils-evt21.raw")
            to_little(out / "street.evutils-evt21.raw", out / "street.evt21-little.raw")
            np.save(out / "street-2000.npy", small)
            part = built_stream(2, 300)
            write_words(part, out / "vectors.evt21-legacy.raw", True)
            write_words(part, out / "vectors.evt21-little.raw", False)
            v = evutils_read(out / "vectors.evt21-legacy.raw")
            compare("fixture: evlib against evutils", evlib_read(out / "vectors.evt21-little.raw"),
                    v)
            np.save(out / "vectors.npy", v)
            compare("fixture: evutils re-reads its street file",
                    evutils_read(out / "street.evutils-evt21.raw"), small)
            print(f"fixtures in {out}")
        if a.firmware_asset:
            first = street[:7500]
            evutils_write(first, (346, 260), d / "first.raw")
            to_little(d / "first.raw", d / "first-little.raw")
            compare("firmware asset: evlib reads the words", evlib_read(d / "first-little.raw"),
                    first)
            a.firmware_asset.write_bytes(split(d / "first-little.raw")[1])
            print(f"wrote {a.firmware_asset}")
    if failures:
        print(f"{len(failures)} comparison(s) failed")
        sys.exit(1)
    print("all comparisons agree")


if __name__ == "__main__":
    main()
