#!/usr/bin/env python3
"""Reads AEDAT 4 files with iniVation's dv-processing (the library DV tools are built on) and
prints, per camera (stream source), its resolution and the events dv-processing returns: the
check that `evpose convert --out F.aedat4` writes files DV tools read.

usage: python3 -m venv /tmp/dv && /tmp/dv/bin/pip install dv-processing==2.0.4
       /tmp/dv/bin/python scripts/dv-processing-check.py F.aedat4 [F2.aedat4 ...]
"""
import re
import sys

import dv_processing as dv


def count(reader):
    n = 0
    while reader.isRunning():
        batch = reader.getNextEventBatch()
        if batch is not None:
            n += batch.size()
    return n


status = 0
for path in sys.argv[1:]:
    head = open(path, "rb").read(1 << 16).decode("latin1")
    sources = re.findall(r'key="source" type="string">([^<]*)<', head)
    if not sources:
        print(f"{path}: no stream names a source: dv-processing finds no camera")
        status = 1
    for source in sources:
        try:
            r = dv.io.MonoCameraRecording(path, source)
            print(f"{path}: {source}: {r.getEventResolution()}, {count(r)} events")
        except Exception as e:  # dv-processing raises RuntimeError with its own message
            print(f"{path}: {source}: FAILED: {str(e).splitlines()[0][:200]}")
            status = 1
sys.exit(status)
