#!/usr/bin/env python3
"""Convert a copy of the official T2M text-motion evaluator (Guo et al. 2022, as MDM downloads
it) into the directory `diffkfc eval --evaluator t2m:DIR` reads.

    python3 scripts/convert-t2m-evaluator.py \
        --checkpoint t2m/text_mot_match/model/finest.tar \
        --glove glove/ \
        --mean t2m/Comp_v6_KLD01/meta/mean.npy --std t2m/Comp_v6_KLD01/meta/std.npy \
        --out work/t2m-evaluator

Needs torch (to read the .tar) and numpy. Writes evaluator.safetensors (every tensor of the
movement, text and motion encoders, named `<module>.<state-dict key>`, float32), glove.npy and
glove_words.txt (the vocabulary in index order), mean.npy and std.npy (float32).
"""
import argparse
import json
import os
import pickle
import struct
import sys

import numpy as np

MODULES = ("movement_encoder", "text_encoder", "motion_encoder")


def write_safetensors(path, tensors):
    """The safetensors format by hand (an 8-byte header length, a JSON header, raw data)."""
    header, blobs, offset = {}, [], 0
    for name in sorted(tensors):
        a = np.ascontiguousarray(tensors[name], dtype="<f4")
        header[name] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [offset, offset + a.nbytes]}
        blobs.append(a.tobytes())
        offset += a.nbytes
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for b in blobs:
            f.write(b)
    os.replace(tmp, path)


def save_npy(path, a):
    tmp = path + ".tmp.npy"
    np.save(tmp, a)
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True, help="text_mot_match/model/finest.tar")
    ap.add_argument("--glove", required=True, help="folder with our_vab_data.npy, our_vab_words.pkl, our_vab_idx.pkl")
    ap.add_argument("--mean", required=True, help="the evaluator's mean.npy (MDM: dataset/t2m_mean.npy)")
    ap.add_argument("--std", required=True, help="the evaluator's std.npy (MDM: dataset/t2m_std.npy)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    import torch

    # The .tar holds state dicts and counters; it is the user's own file, so it is unpickled whole.
    ck = torch.load(a.checkpoint, map_location="cpu", weights_only=False)
    missing = [m for m in MODULES if m not in ck]
    if missing:
        sys.exit(f"error: {a.checkpoint}: no {', '.join(missing)} (is this text_mot_match/model/finest.tar?)")
    tensors = {f"{m}.{k}": v.detach().float().numpy() for m in MODULES for k, v in ck[m].items()}
    vectors = np.load(os.path.join(a.glove, "our_vab_data.npy")).astype(np.float32)
    with open(os.path.join(a.glove, "our_vab_words.pkl"), "rb") as f:
        words = pickle.load(f)
    with open(os.path.join(a.glove, "our_vab_idx.pkl"), "rb") as f:
        idx = pickle.load(f)
    order = sorted(words, key=lambda w: idx[w])
    if [idx[w] for w in order] != list(range(len(order))) or len(order) != vectors.shape[0]:
        sys.exit(f"error: {a.glove}: the word index does not cover 0..{vectors.shape[0] - 1}")
    mean, std = np.load(a.mean).astype(np.float32), np.load(a.std).astype(np.float32)
    os.makedirs(a.out, exist_ok=True)
    write_safetensors(os.path.join(a.out, "evaluator.safetensors"), tensors)
    save_npy(os.path.join(a.out, "glove.npy"), vectors)
    with open(os.path.join(a.out, "glove_words.txt"), "w") as f:
        f.write("".join(w + "\n" for w in order))
    save_npy(os.path.join(a.out, "mean.npy"), mean)
    save_npy(os.path.join(a.out, "std.npy"), std)
    n = sum(v.size for v in tensors.values())
    print(f"{a.out}: {len(tensors)} tensors ({n / 1e6:.2f} M parameters), {len(order)} words, {mean.size} features")


if __name__ == "__main__":
    main()
