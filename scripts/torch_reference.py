#!/usr/bin/env python3
"""The PyTorch reference network of ../shared/bench/reference_diffkfc.py (imported from there,
not copied) at every preset `diffkfc bench` knows, eager or under torch.compile, for side-by-side
timing. Prints one JSON line like the reference script's: train_step_ms (forward + backward +
Adam at --batch) and cfg_call_ms (a no-grad forward at batch 2, one guided sampling step).

  python scripts/torch_reference.py --config mid --batch 32 --steps 3 [--compile] [--device cuda]

--device cuda runs it on the GPU (the timings then wait for the GPU: torch.cuda.synchronize).

The reference's directory: $DIFFKFC_TORCH_REFERENCE_DIR, else ../shared/bench beside the repo.
"""
import argparse
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.environ.get("DIFFKFC_TORCH_REFERENCE_DIR", os.path.join(HERE, "..", "..", "shared", "bench")))

import torch  # noqa: E402
from reference_diffkfc import DiffKFC  # noqa: E402

# diffkfc's presets in the reference's constructor arguments (crates/model/src/network/config.rs);
# "None" is the DMA block over every frame (our 0).
PRESETS = {
    "paper": dict(d=512, heads=8, ff=1024, dec_layers=8),
    "torch-tiny": dict(d=128, heads=4, ff=256, dec_layers=4, enc_sizes=(2, 4, 8, None)),
    "small": dict(d=256, heads=4, ff=512, dec_layers=4, enc_sizes=(2, 4, 8, None)),
    "mid": dict(d=128, heads=4, ff=256, dec_layers=3, enc_sizes=(2, 4, None)),
    "tiny": dict(d=64, heads=4, ff=128, dec_layers=2, enc_sizes=(2, 4, None)),
}


def inputs(bs, frames, device):
    x = torch.randn(bs, frames, 263, device=device)
    t = torch.randint(0, 1000, (bs,), device=device)
    c = torch.randn(bs, 384, device=device)
    valid = torch.rand(bs, frames, device=device) < 0.05
    valid[:, 0] = True
    return x, t, c, x * valid[..., None], valid


def sync(device):
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def median_ms(fn, warmup, runs, device):
    for _ in range(warmup):
        fn()
    sync(device)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        sync(device)
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--config", choices=sorted(PRESETS), default="tiny")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--compile", action="store_true", help="torch.compile the model (inductor)")
    p.add_argument("--device", default="cpu", help="cpu, or cuda (cuda:N) for the GPU")
    a = p.parse_args()
    torch.manual_seed(0)
    # The reference makes its masks and frequencies inside forward on the default device.
    torch.set_default_device(a.device)
    model = DiffKFC(**PRESETS[a.config]).to(a.device)
    params = sum(q.numel() for q in model.parameters())
    opt = torch.optim.Adam(model.parameters(), 1e-4)
    run = torch.compile(model) if a.compile else model
    x, t, c, kf, v = inputs(a.batch, a.frames, a.device)

    def train_step():
        loss = ((run(x, t, c, kf, v) - x) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    model.train()
    t0 = time.perf_counter()
    train_step()  # the first call compiles under --compile
    sync(a.device)
    first_ms = (time.perf_counter() - t0) * 1000
    train_ms = median_ms(train_step, 1, a.steps, a.device)
    model.eval()
    x2, t2, c2, kf2, v2 = inputs(2, a.frames, a.device)

    def call():
        with torch.no_grad():
            run(x2, t2, c2, kf2, v2)

    call_ms = median_ms(call, 2, a.steps * 4, a.device)
    print(json.dumps(dict(
        impl="pytorch-compile" if a.compile else "pytorch", torch=torch.__version__,
        threads=torch.get_num_threads(), device=a.device, config=a.config, params=params, batch=a.batch,
        frames=a.frames, compiled=a.compile, first_step_ms=round(first_ms, 1),
        train_step_ms=round(train_ms, 1), cfg_call_ms=round(call_ms, 1))))


if __name__ == "__main__":
    main()
