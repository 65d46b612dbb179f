#!/usr/bin/env python3
"""PyTorch's offline throughput for the network `slipguard bench-host` measures.

Variant (c) of the paper at hidden 128: nn.LSTM(input 11 = force + 10 STFT bands,
hidden 128), then nn.Linear(128, 2) and softmax, float32 on the CPU, the whole sequence in
one call (offline: PyTorch's fastest mode, the batch and time steps in one tensor). The STFT
front end is not included (the slipguard figures include it). Per batch size B and thread
count T: channel-steps per second = B x steps / seconds.

    python3 scripts/bench_torch_lstm.py --out out/torch.json
    slipguard bench-host --torch out/torch.json      # or: slipguard bench-host --run-torch
"""
import argparse
import json
import time

import torch


def measure(lstm, head, batch, inputs, seconds):
    # Enough steps per call that one call is a few milliseconds at least (and bounded memory).
    steps = max(8, min(2000, 200_000 // batch))
    x = torch.randn(steps, batch, inputs)
    with torch.inference_mode():
        p = torch.softmax(head(lstm(x)[0]), dim=-1)  # warm-up
        done, t0 = 0, time.perf_counter()
        while True:
            p = torch.softmax(head(lstm(x)[0]), dim=-1)
            done += steps * batch
            dt = time.perf_counter() - t0
            if dt >= seconds:
                break
    assert p.shape == (steps, batch, 2)
    return done / dt


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", default="1,16,256,4096", help="batch sizes, comma-separated")
    ap.add_argument("--threads", default="1,2", help="thread counts, comma-separated")
    ap.add_argument("--seconds", type=float, default=1.0, help="seconds per measurement")
    ap.add_argument("--inputs", type=int, default=11, help="LSTM input size (force + 10 bands)")
    ap.add_argument("--hidden", type=int, default=128, help="LSTM hidden size")
    ap.add_argument("--out", required=True, help="JSON result file")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    a = ap.parse_args()
    torch.manual_seed(0)
    lstm = torch.nn.LSTM(a.inputs, a.hidden).eval()
    head = torch.nn.Linear(a.hidden, 2).eval()
    results = []
    for b in [int(v) for v in a.batch.split(",")]:
        for t in [int(v) for v in a.threads.split(",")]:
            torch.set_num_threads(t)
            r = measure(lstm, head, b, a.inputs, a.seconds)
            results.append({"batch": b, "threads": t, "channel_steps_per_s": r})
            if not a.quiet:
                print(f"torch nn.LSTM batch {b:>4}, {t} thread(s): {r:12.0f} channel-steps/s")
    with open(a.out, "w") as f:
        json.dump(
            {
                "torch": torch.__version__,
                "inputs": a.inputs,
                "hidden": a.hidden,
                "results": results,
            },
            f,
            indent=1,
        )


if __name__ == "__main__":
    main()
