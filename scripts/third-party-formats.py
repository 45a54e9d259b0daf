#!/usr/bin/env python3
"""evpose's readers and its AEDAT 4, EVT 3.0 and EVT 2.0 writers against independent engines: expelliarmus (C; EVT 2.0,
EVT 3.0, DAT), faery (Rust; EVT 2.0, EVT 3.0, DAT 1 and 2, AEDAT 4, CSV, Event Stream) and
aedat (Rust; AEDAT 4).

1. Each engine writes the street recording's events (`../shared/recordings/davis346-street.aedat4`,
   read by `evpose convert`, times from 0), 64 events over 40 s on 1280 x 720, rows of same-time
   events, and the street events inside 304 x 240 (DAT version 1) in every format it writes;
   `evpose convert` reads each file back; the events must equal the ones written, exactly.
2. The engines read evpose's AEDAT 4 (the street events, and the bundled four-camera clip), its
   EVT 3.0 (`convert --out F.raw`: faery exactly, expelliarmus in x, y and polarity), its EVT 2.0
   (`--encoding evt2`: both exactly) and the
   spec-built fixtures in host/tests/fixtures/formats; they must read what evpose reads.
3. `--real DIR`: real camera files read by evpose and the engines: Prophesee RAW (`*.raw`, e.g.
   expelliarmus's test files `evt2_sample.raw` and `evt3_sample.raw`,
   github.com/open-neuromorphic/expelliarmus, tests/sample-files) against both engines, and
   Event Stream (`*.es`, e.g. `examples/dvs.es` of github.com/neuromorphic-paris/event_stream)
   against faery.
4. `--write-fixtures DIR`: the small files `host/tests/third_party.rs` reads, written by each
   engine: 2,000 street events; 64 events over 40 s on a 1280 x 720 sensor (EVT 3.0's time
   wraps after 16.8 s); 24 rows of events at one timestamp each (EVT 3.0 vector words); and
   faery's DAT version 1 of 1,000 street events inside a 304 x 240 sensor.

5. `--firmware-asset PATH`: faery's EVT 3.0 words (the header cut off) of the street recording's
   first 7,500 events, the firmware's boot check of the core's EVT decoder
   (`firmware/assets/street-00.evt3`).
usage: python3 -m venv /tmp/tp && /tmp/tp/bin/pip install expelliarmus==1.1.12 faery==0.7.1 \\
           aedat==2.3.0
       /tmp/tp/bin/python scripts/third-party-formats.py [--evpose target/release/evpose] \\
           [--real DIR] [--write-fixtures DIR] [--firmware-asset PATH]
Exit status 1 when any comparison fails.
"""
import argparse
import pathlib
import subprocess
import sys
import tempfile

import aedat
import expelliarmus
import faery
import numpy as np

from engine_check import REPO, STREET, compare, evpose_read, failures, report

CLIP = REPO / "assets" / "clip" / "S4242-00_side-kick.aedat"
FIXTURES = REPO / "host" / "tests" / "fixtures" / "formats"
EXPELLIARMUS = {"evt2": "raw", "evt3": "raw", "dat": "dat"}
FAERY = {"evt2": "raw", "evt3": "raw", "dat2": "dat", "aedat4": "aedat4", "csv": "csv",
         "es": "es"}


def structured(ev):
    """(N, 4) [x, y, t, p] to expelliarmus's and faery's structured arrays."""
    ex = np.zeros(len(ev), dtype=[("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
    fa = np.zeros(len(ev), dtype=faery.EVENTS_DTYPE)
    for a in (ex, fa):
        a["t"], a["x"], a["y"] = ev[:, 2], ev[:, 0], ev[:, 1]
    ex["p"] = ev[:, 3]
    fa["on"] = ev[:, 3] == 1
    return ex, fa


def as_rows(t, x, y, p):
    return np.stack([np.asarray(x, np.int64), np.asarray(y, np.int64), np.asarray(t, np.int64),
                     np.asarray(p, np.int64)], axis=1)


def write_all(ev, size, out, stem, only=None):
    """Every engine's file of the events `ev` (or those named in `only`); [(name, path)]."""
    ex, fa = structured(ev)
    files = []
    for enc, ext in EXPELLIARMUS.items():
        if only and f"expelliarmus {enc}" not in only:
            continue
        path = out / f"{stem}.expelliarmus-{enc}.{ext}"
        expelliarmus.Wizard(encoding=enc).save(str(path), ex)
        files.append((f"expelliarmus {enc}", path))
    faery_formats = dict(FAERY)
    if size[0] <= 512 and size[1] <= 256:
        faery_formats["dat1"] = "dat"  # 9-bit x, 8-bit y
    for version, ext in faery_formats.items():
        if only and f"faery {version}" not in only:
            continue
        path = out / f"{stem}.faery-{version}.{ext}"
        kw = {"version": version} if ext in ("raw", "dat") else {}
        faery.events_stream_from_array(fa, size).to_file(str(path), zero_t0=False, **kw)
        files.append((f"faery {version}", path))
    return files


def faery_read(path):
    a = np.concatenate(list(faery.events_stream_from_file(str(path))))
    return as_rows(a["t"], a["x"], a["y"], a["on"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--evpose", default=str(REPO / "target" / "release" / "evpose"))
    ap.add_argument("--real", type=pathlib.Path)
    ap.add_argument("--write-fixtures", type=pathlib.Path)
    ap.add_argument("--firmware-asset", type=pathlib.Path,
                    help="write faery's EVT 3.0 words (no header) of the street recording's "
                         "first 7,500 events here (firmware/assets/street-00.evt3)")
    a = ap.parse_args()
    ev, why = evpose_read(a.evpose, STREET)
    if ev is None:
        sys.exit(f"cannot read {STREET}: {why}")
    ev[:, 2] -= ev[0, 2]
    # An ATIS-sized sensor (304 x 240) for DAT version 1 (9-bit x, 8-bit y).
    atis = ev[(ev[:, 0] < 304) & (ev[:, 1] < 240)]
    # Runs along rows at one timestamp (EVT 3.0 vector words), both polarities, gaps of 1 ms.
    rows_rng = np.random.default_rng(11)
    rows = []
    for k in range(24):
        x = np.nonzero(rows_rng.random(64) < 0.6)[0] + rows_rng.integers(0, 1216)
        rows.append(as_rows(np.full(len(x), 1000 * k), x, np.full(len(x), (37 * k) % 720),
                            np.full(len(x), k % 2)))
    rows = np.concatenate(rows)
    sparse_rng = np.random.default_rng(7)
    sparse = as_rows(np.sort(sparse_rng.integers(0, 40_000_000, 64)),
                     sparse_rng.integers(0, 1280, 64), sparse_rng.integers(0, 720, 64),
                     sparse_rng.integers(0, 2, 64))

    with tempfile.TemporaryDirectory() as d:
        d = pathlib.Path(d)
        # 1. Engines write, evpose reads.
        for stem, events, size in [("street", ev, (346, 260)), ("sparse", sparse, (1280, 720)),
                                   ("rows", rows, (1280, 720)), ("atis", atis, (304, 240))]:
            for name, path in write_all(events, size, d, stem):
                if stem == "sparse" and name == "expelliarmus evt3":
                    continue  # one time-high word per file: gaps of 2,048 us or more are lost
                got, why = evpose_read(a.evpose, path, "--width", str(size[0]),
                                       "--height", str(size[1]))
                compare(f"{stem}: {name} -> evpose", got, events, why)
        # 2. evpose writes AEDAT 4, the engines read; the engines read evpose's fixtures.
        st = d / "street.aedat4"
        np.save(d / "street.npy", ev.astype(np.float64))
        subprocess.run([a.evpose, "convert", str(d / "street.npy"), "--width", "346",
                        "--height", "260", "--out", str(st)], check=True, capture_output=True)
        compare("street: evpose aedat4 -> faery", faery_read(st), ev)
        # evpose's EVT 3.0 writer: faery reads it exactly; expelliarmus's x, y and polarity
        # (its decoder counts a time-low step back as a wrap even after a time-high word).
        for stem, events, size in [("street", ev, (346, 260)), ("sparse", sparse, (1280, 720)),
                                   ("rows", rows, (1280, 720))]:
            src, raw = d / f"{stem}-src.npy", d / f"{stem}-evpose.raw"
            np.save(src, events.astype(np.float64))
            subprocess.run([a.evpose, "convert", str(src), "--width", str(size[0]), "--height",
                            str(size[1]), "--out", str(raw)], check=True, capture_output=True)
            compare(f"{stem}: evpose evt3 -> faery", faery_read(raw), events)
            e = expelliarmus.Wizard(encoding="evt3").read(str(raw))
            compare(f"{stem}: evpose evt3 -> expelliarmus, x y p",
                    as_rows(e["t"], e["x"], e["y"], e["p"])[:, [0, 1, 3]], events[:, [0, 1, 3]])
            # evpose's EVT 2.0 writer (`--encoding evt2`): both engines read it exactly.
            raw2 = d / f"{stem}-evpose-evt2.raw"
            subprocess.run([a.evpose, "convert", str(src), "--width", str(size[0]), "--height",
                            str(size[1]), "--out", str(raw2), "--encoding", "evt2"], check=True,
                           capture_output=True)
            compare(f"{stem}: evpose evt2 -> faery", faery_read(raw2), events)
            e = expelliarmus.Wizard(encoding="evt2").read(str(raw2))
            compare(f"{stem}: evpose evt2 -> expelliarmus",
                    as_rows(e["t"], e["x"], e["y"], e["p"]), events)
        clip = d / "clip.aedat4"
        subprocess.run([a.evpose, "convert", str(CLIP), "--out", str(clip)], check=True,
                       capture_output=True)
        per_stream = {}
        for packet in aedat.Decoder(str(clip)):
            if "events" in packet:
                e = packet["events"]
                per_stream.setdefault(packet["stream_id"], []).append(
                    as_rows(e["t"], e["x"], e["y"], e["on"]))
        for cam in range(4):
            want, why = evpose_read(a.evpose, CLIP, "--camera", str(cam))
            got = np.concatenate(per_stream.get(cam, [np.zeros((0, 4), np.int64)]))
            compare(f"clip camera {cam}: evpose aedat4 -> aedat", got, want, why)
        for name, enc in [("evt2.raw", "evt2"), ("evt3.raw", "evt3"), ("cd.dat", "dat")]:
            want, why = evpose_read(a.evpose, FIXTURES / name, "--width", "1280", "--height",
                                    "720")
            e = expelliarmus.Wizard(encoding=enc).read(str(FIXTURES / name))
            compare(f"fixture {name} -> expelliarmus", as_rows(e["t"], e["x"], e["y"], e["p"]),
                    want, why)
            compare(f"fixture {name} -> faery", faery_read(FIXTURES / name), want, why)
    # 3. Real camera files: x, y and polarity must equal both engines'; EVT 3.0 times are
    # reported, not required equal. evpose decodes a time-low word as OpenEB does (the time low
    # as given, also when it is below the one before: the real EVT 3.0 file has such words);
    # faery keeps the larger time low, expelliarmus counts every decrease as a wrap.
    if a.real:
        for raw in sorted(a.real.glob("*.raw")):
            got, why = evpose_read(a.evpose, raw)
            if got is None:
                report(f"real {raw.name}", False, why)
                continue
            enc = "evt3" if b"evt 3.0" in raw.read_bytes()[:4096] else "evt2"
            e = expelliarmus.Wizard(encoding=enc).read(str(raw))
            for engine, want in [("expelliarmus", as_rows(e["t"], e["x"], e["y"], e["p"])),
                                 ("faery", faery_read(raw))]:
                name = f"real {raw.name} ({enc}): evpose against {engine}"
                if enc == "evt2":
                    compare(name, got, want)
                    continue
                cols = [0, 1, 3]
                compare(name + ", x y p", got[:, cols], want[:, cols])
                dt = want[:, 2] - got[:, 2]
                print(f"     times: {np.count_nonzero(dt)} of {len(dt)} differ "
                      f"(by {dt.min()} to {dt.max()} us)")
        for es in sorted(a.real.glob("*.es")):
            got, why = evpose_read(a.evpose, es)
            compare(f"real {es.name}: evpose against faery", got, faery_read(es), why)
    # 4. The committed fixtures.
    if a.write_fixtures:
        out = a.write_fixtures
        out.mkdir(parents=True, exist_ok=True)
        for stem, events, size, only in [
                ("street", ev[:2000], (346, 260), None),
                ("sparse", sparse, (1280, 720), None),
                ("rows", rows, (1280, 720), None),
                ("atis", atis[:1000], (304, 240), ["faery dat1"])]:
            np.save(out / f"{stem}.npy", events.astype(np.int32))
            for name, path in write_all(events, size, out, stem, only):
                if stem == "sparse" and name == "expelliarmus evt3":
                    path.unlink()
        print(f"fixtures in {out}")
    # 5. The firmware's EVT 3.0 asset: the words alone, as a sensor streams them.
    if a.firmware_asset:
        with tempfile.TemporaryDirectory() as d:
            raw = pathlib.Path(d) / "street-00.raw"
            _, fa = structured(ev[:7500])
            faery.events_stream_from_array(fa, (346, 260)).to_file(
                str(raw), version="evt3", zero_t0=False)
            data = raw.read_bytes()
            body = 0
            while data[body:body + 1] == b"%":
                body = data.index(b"\n", body) + 1
            a.firmware_asset.write_bytes(data[body:])
            print(f"{a.firmware_asset}: {len(data) - body} bytes of EVT 3.0 words")
    print(f"{len(failures)} failed" if failures else "all equal")
    sys.exit(1 if failures else 0)


main()
