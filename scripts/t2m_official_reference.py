#!/usr/bin/env python3
"""The T2M evaluator's embeddings made by the official modules themselves (Guo et al. 2022,
https://github.com/EricGuo5513/text-to-motion: `networks/modules.py` and
`utils/word_vectorizer.py`), imported from a local copy of that repository at recording time:
their code is not part of diffkfc, only the numbers this writes.

    git clone https://github.com/EricGuo5513/text-to-motion /tmp/t2m     # any copy of it
    python3 scripts/t2m_reference.py record OUT --fixtures ../shared/fixtures
    python3 scripts/t2m_official_reference.py OUT --official /tmp/t2m --fixtures ../shared/fixtures

OUT is a folder of `t2m_reference.py record` (its source/finest.tar, vocabulary, mean/std,
motions/*.txt, captions.txt); this writes OUT/official/expected_motion.npy and
expected_text.npy. Inputs are prepared as the official `Text2MotionDatasetV2.__getitem__` does
(lengths floored to 4, normalised, zero-padded to max_motion_length 196; tokens between
sos/OTHER and eos/OTHER, padded with unk/OTHER to 22, at most 20 kept) and embedded as
`EvaluatorModelWrapper.get_co_embeddings` does (sorted by length for the packed GRUs, eval mode).
crates/eval/tests/t2m.rs checks diffkfc against both references.
"""
import argparse
import os
import sys

import numpy as np
import torch

MAX_MOTION_LENGTH, MAX_TEXT_LEN, UNIT = 196, 20, 4


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recorded")
    ap.add_argument("--official", required=True, help="a copy of the text-to-motion repository")
    ap.add_argument("--fixtures", required=True)
    a = ap.parse_args()
    sys.path.insert(0, os.path.abspath(a.official))
    from networks.modules import MotionEncoderBiGRUCo, MovementConvEncoder, TextEncoderBiGRUCo
    from utils.word_vectorizer import WordVectorizer

    src = os.path.join(a.recorded, "source")
    ck = torch.load(os.path.join(src, "finest.tar"), map_location="cpu")
    conv1, conv2 = ck["movement_encoder"]["main.0.weight"], ck["movement_encoder"]["main.3.weight"]
    word = ck["text_encoder"]["pos_emb.weight"].shape[0]
    text_hidden = ck["text_encoder"]["input_emb.weight"].shape[0]
    motion_hidden = ck["motion_encoder"]["input_emb.weight"].shape[0]
    embed = ck["text_encoder"]["output_net.3.weight"].shape[0]
    movement = MovementConvEncoder(conv1.shape[1], conv1.shape[0], conv2.shape[0])
    text = TextEncoderBiGRUCo(word_size=word, pos_size=15, hidden_size=text_hidden, output_size=embed, device="cpu")
    motion = MotionEncoderBiGRUCo(input_size=conv2.shape[0], hidden_size=motion_hidden, output_size=embed, device="cpu")
    for m, k in [(movement, "movement_encoder"), (text, "text_encoder"), (motion, "motion_encoder")]:
        m.load_state_dict(ck[k])
        m.eval()
    vectorizer = WordVectorizer(src, "our_vab")
    mean, std = np.load(os.path.join(src, "mean.npy")), np.load(os.path.join(src, "std.npy"))

    motions, lens = [], []
    for k in range(len(os.listdir(os.path.join(a.recorded, "motions")))):
        rel, start, frames = open(os.path.join(a.recorded, "motions", f"{k}.txt")).read().split()
        m = np.load(os.path.join(a.fixtures, rel))[int(start): int(start) + int(frames)]
        n = len(m) // UNIT * UNIT
        m = (m[:n] - mean) / std
        motions.append(np.concatenate([m, np.zeros((MAX_MOTION_LENGTH - n, m.shape[1]))], axis=0))
        lens.append(n)
    x = torch.from_numpy(np.stack(motions)).float()
    order = np.argsort(lens)[::-1].copy()
    with torch.no_grad():
        codes = movement(x[order][..., :-4])
        emb = motion(codes, torch.tensor(np.array(lens)[order]) // UNIT).numpy()
    motion_emb = np.zeros_like(emb)
    motion_emb[order] = emb

    words, pos, sent = [], [], []
    for line in open(os.path.join(a.recorded, "captions.txt")):
        tokens = line.split("#")[1].split()
        if len(tokens) < MAX_TEXT_LEN:
            tokens = ["sos/OTHER"] + tokens + ["eos/OTHER"]
            sent.append(len(tokens))
            tokens = tokens + ["unk/OTHER"] * (MAX_TEXT_LEN + 2 - len(tokens))
        else:
            tokens = ["sos/OTHER"] + tokens[:MAX_TEXT_LEN] + ["eos/OTHER"]
            sent.append(len(tokens))
        pairs = [vectorizer[t] for t in tokens]
        words.append(np.stack([p[0] for p in pairs]))
        pos.append(np.stack([p[1] for p in pairs]))
    order = np.argsort(sent)[::-1].copy()
    with torch.no_grad():
        emb = text(torch.from_numpy(np.stack(words)[order]).float(), torch.from_numpy(np.stack(pos)[order]).float(),
                   torch.tensor(np.array(sent)[order])).numpy()
    text_emb = np.zeros_like(emb)
    text_emb[order] = emb

    out = os.path.join(a.recorded, "official")
    os.makedirs(out, exist_ok=True)
    np.save(os.path.join(out, "expected_motion.npy"), motion_emb.astype(np.float32))
    np.save(os.path.join(out, "expected_text.npy"), text_emb.astype(np.float32))
    print(f"{out}: {len(lens)} motions and {len(sent)} captions embedded by the official modules")


if __name__ == "__main__":
    main()
