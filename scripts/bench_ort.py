#!/usr/bin/env python3
"""onnxruntime's own int8 quantization of a float model, timed on one thread: the peer that
`evpose bench infer` is compared with (QOperator, u8 activations, s8 per-channel weights).

usage: bench_ort.py MODEL.onnx POINTS.npy [ITERATIONS]
POINTS.npy: an (N, 5) float32 point cloud (N = the model's point count).
Prints JSON: median ms of onnxruntime f32 and int8 (QOperator and QDQ), and each one's fastest run
(`*_fastest_ms`: on a shared machine, the figure least disturbed by other work)."""
import json, os, statistics, sys, tempfile, time

import numpy as np
import onnxruntime as ort
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static


class OneInput(CalibrationDataReader):
    def __init__(self, x):
        self.items = iter([{"points": x}])

    def get_next(self):
        return next(self.items, None)


def times_ms(path, x, iterations):
    """(median, fastest) ms of `iterations` runs on one thread, after one warm-up run."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    s = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    s.run(None, {"points": x})
    t = []
    for _ in range(iterations):
        start = time.perf_counter()
        s.run(None, {"points": x})
        t.append((time.perf_counter() - start) * 1e3)
    # The median as `evpose bench infer` takes it: the mean of the two middle runs for an even
    # count (since stop 42; the upper one before, in both).
    return statistics.median(t), min(t)


def main():
    model, points = sys.argv[1], sys.argv[2]
    iterations = int(sys.argv[3]) if len(sys.argv) > 3 else 10
    x = np.load(points).astype(np.float32).T[None].copy()
    out = {"onnxruntime_version": ort.__version__, "points": x.shape[2]}
    out["ort_f32_ms"], out["ort_f32_fastest_ms"] = times_ms(model, x, iterations)
    with tempfile.TemporaryDirectory() as d:
        for fmt, name in [(QuantFormat.QOperator, "ort_int8_qoperator_ms"), (QuantFormat.QDQ, "ort_int8_qdq_ms")]:
            q = os.path.join(d, name + ".onnx")
            quantize_static(model, q, OneInput(x), quant_format=fmt, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8, per_channel=True)
            out[name], out[name.replace("_ms", "_fastest_ms")] = times_ms(q, x, iterations)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
