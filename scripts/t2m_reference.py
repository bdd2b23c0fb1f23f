#!/usr/bin/env python3
"""An independent PyTorch implementation of the T2M evaluator's three modules (movement
encoder, text and motion BiGRU encoders, as the published layout describes them), used to check
diffkfc's `t2m` evaluator: it makes a small evaluator with random weights in the original
`finest.tar` layout with a GloVe-style vocabulary, and embeds motions and captions with
PyTorch's own GRU and packed sequences.

    python3 scripts/t2m_reference.py record OUT --fixtures ../shared/fixtures

writes OUT/source (the .tar, vocabulary, mean/std), OUT/converted (through
scripts/convert-t2m-evaluator.py), OUT/captions.txt, OUT/motions/*.npy and the embeddings
OUT/expected_motion.npy and OUT/expected_text.npy. crates/eval/tests/t2m.rs compares diffkfc's
embeddings with them (a recorded copy lives in crates/eval/tests/t2m/).
"""
import argparse
import os
import pickle
import subprocess
import sys

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

POS = ["VERB", "NOUN", "DET", "ADP", "NUM", "AUX", "PRON", "ADJ", "ADV", "Loc_VIP", "Body_VIP",
       "Obj_VIP", "Act_VIP", "Desc_VIP", "OTHER"]
VIP = {
    "Loc_VIP": "left right clockwise counterclockwise anticlockwise forward back backward up down straight curve",
    "Body_VIP": "arm chin foot feet face hand mouth leg waist eye knee shoulder thigh",
    "Obj_VIP": "stair dumbbell chair window floor car ball handrail baseball basketball",
    "Act_VIP": "walk run swing pick bring kick put squat throw hop dance jump turn stumble stop sit lift lower "
               "raise wash stand kneel stroll rub bend balance flap jog shuffle lean rotate spin spread climb",
    "Desc_VIP": "slowly carefully fast careful slow quickly happy angry sad happily angrily sadly",
}
# Small sizes for the recorded test (the real evaluator: word 300, text hidden 512, movement 512,
# motion hidden 1024, embedding 512).
SIZES = dict(word=12, text_hidden=16, move_hidden=16, move_latent=12, motion_hidden=20, embed=8)
FULL = dict(word=300, text_hidden=512, move_hidden=512, move_latent=512, motion_hidden=1024, embed=512)
# HumanML3D-style captions: a VIP word tagged otherwise, an out-of-vocabulary word ("zigzags",
# left out of the vocabulary below) and one caption past 20 tokens.
CAPTIONS = [
    "a person walks forward and waves his left hand.#a/DET person/NOUN walk/VERB forward/ADV and/CCONJ wave/VERB his/DET left/ADJ hand/NOUN",
    "someone jumps up twice.#someone/PRON jump/VERB up/ADP twice/ADV",
    "a man zigzags slowly to the right.#a/DET man/NOUN zigzags/VERB slowly/ADV to/ADP the/DET right/NOUN",
    "the person walks in a circle then turns around and sits down on a chair while raising both arms above the head.#the/DET person/NOUN walk/VERB in/ADP a/DET circle/NOUN then/ADV turn/VERB around/ADV and/CCONJ sit/VERB down/ADP on/ADP a/DET chair/NOUN while/SCONJ raise/VERB both/DET arm/NOUN above/ADP the/DET head/NOUN",
]
# (fixture features, first frame, frames): lengths 168, 176, 40 and 96 after flooring to 4.
MOTIONS = [("humanml3d/new_joint_vecs/012314.npy", 0, 170), ("humanml3d/000021_features_reference.npy", 0, 179),
           ("humanml3d/new_joint_vecs/012314.npy", 0, 42), ("humanml3d/new_joint_vecs/012314.npy", 10, 96)]


class MovementEncoder(nn.Module):
    def __init__(self, d_in, hidden, latent):
        super().__init__()
        self.main = nn.Sequential(nn.Conv1d(d_in, hidden, 4, 2, 1), nn.Dropout(0.2), nn.LeakyReLU(0.2),
                                  nn.Conv1d(hidden, latent, 4, 2, 1), nn.Dropout(0.2), nn.LeakyReLU(0.2))
        self.out_net = nn.Linear(latent, latent)

    def forward(self, x):  # [B, T, D] -> [B, T / 4, latent]
        return self.out_net(self.main(x.permute(0, 2, 1)).permute(0, 2, 1))


class BiGruEncoder(nn.Module):
    def __init__(self, d_in, hidden, out):
        super().__init__()
        self.input_emb = nn.Linear(d_in, hidden)
        self.gru = nn.GRU(hidden, hidden, batch_first=True, bidirectional=True)
        self.output_net = nn.Sequential(nn.Linear(2 * hidden, hidden), nn.LayerNorm(hidden), nn.LeakyReLU(0.2),
                                        nn.Linear(hidden, out))
        self.hidden = nn.Parameter(torch.randn(2, 1, hidden))

    def forward(self, x, lens):
        e = self.input_emb(x)
        packed = pack_padded_sequence(e, torch.tensor(lens), batch_first=True, enforce_sorted=False)
        _, last = self.gru(packed, self.hidden.repeat(1, x.shape[0], 1))
        return self.output_net(torch.cat([last[0], last[1]], dim=-1))


class TextEncoder(BiGruEncoder):
    def __init__(self, word, hidden, out):
        super().__init__(word, hidden, out)
        self.pos_emb = nn.Linear(len(POS), word)

    def forward(self, words, pos, lens):
        return super().forward(words + self.pos_emb(pos), lens)


def build(s):
    torch.manual_seed(0)
    enc = {"movement_encoder": MovementEncoder(259, s["move_hidden"], s["move_latent"]),
           "text_encoder": TextEncoder(s["word"], s["text_hidden"], s["embed"]),
           "motion_encoder": BiGruEncoder(s["move_latent"], s["motion_hidden"], s["embed"])}
    for m in enc.values():
        if s is SIZES:  # small: larger than PyTorch's default init, so that every part matters
            for p in m.parameters():
                nn.init.uniform_(p, -0.5, 0.5)
        m.eval()
    return enc


def tokens(caption):
    return [tuple(t.rsplit("/", 1)) for t in caption.split("#")[1].split()]


def pos_slot(word, tag):
    for group, words in VIP.items():
        if word in words.split():
            return POS.index(group)
    return POS.index(tag) if tag in POS else POS.index("OTHER")


def embed_texts(enc, vocab, vectors, captions):
    seqs = [[("sos", "OTHER")] + tokens(c)[:20] + [("eos", "OTHER")] for c in captions]
    n = 22
    words = np.zeros((len(seqs), n, vectors.shape[1]), np.float32)
    pos = np.zeros((len(seqs), n, len(POS)), np.float32)
    for i, s in enumerate(seqs):
        s = s + [("unk", "OTHER")] * (n - len(s))
        for j, (w, t) in enumerate(s):
            if w in vocab:
                words[i, j], pos[i, j, pos_slot(w, t)] = vectors[vocab[w]], 1
            else:
                words[i, j], pos[i, j, POS.index("OTHER")] = vectors[vocab["unk"]], 1
    with torch.no_grad():
        return enc["text_encoder"](torch.from_numpy(words), torch.from_numpy(pos), [len(s) for s in seqs]).numpy()


# The official loaders zero-pad every normalised motion to max_motion_length frames.
MAX_MOTION_LENGTH = 196


def embed_motions(enc, mean, std, motions):
    lens = [m.shape[0] // 4 * 4 for m in motions]
    x = np.zeros((len(motions), max(MAX_MOTION_LENGTH, max(lens)), 259), np.float32)
    for i, m in enumerate(motions):
        x[i, : lens[i]] = ((m[: lens[i]] - mean) / std)[:, :-4]
    with torch.no_grad():
        codes = enc["movement_encoder"](torch.from_numpy(x))
        return enc["motion_encoder"](codes, [l // 4 for l in lens]).numpy()


def record(out, fixtures, sizes=SIZES):
    src = os.path.join(out, "source")
    os.makedirs(os.path.join(out, "motions"), exist_ok=True)
    os.makedirs(src, exist_ok=True)
    enc = build(sizes)
    torch.save({k: m.state_dict() for k, m in enc.items()} | {"epoch": 0, "iter": 0}, os.path.join(src, "finest.tar"))
    words = sorted({w for c in CAPTIONS for w, _ in tokens(c)} - {"zigzags"}) + ["unk", "sos", "eos"]
    vectors = np.random.default_rng(1).uniform(-1, 1, (len(words), sizes["word"])).astype(np.float32)
    np.save(os.path.join(src, "our_vab_data.npy"), vectors)
    with open(os.path.join(src, "our_vab_words.pkl"), "wb") as f:
        pickle.dump(words, f)
    with open(os.path.join(src, "our_vab_idx.pkl"), "wb") as f:
        pickle.dump({w: i for i, w in enumerate(words)}, f)
    # Our own normalisation statistics (the real evaluator's are third-party data).
    stats = np.random.default_rng(2)
    mean = stats.normal(0, 0.2, 263).astype(np.float32)
    std = stats.uniform(0.2, 2.0, 263).astype(np.float32)
    np.save(os.path.join(src, "mean.npy"), mean)
    np.save(os.path.join(src, "std.npy"), std)
    here = os.path.dirname(os.path.abspath(__file__))
    subprocess.run([sys.executable, os.path.join(here, "convert-t2m-evaluator.py"), "--checkpoint", os.path.join(src, "finest.tar"),
                    "--glove", src, "--mean", os.path.join(src, "mean.npy"), "--std", os.path.join(src, "std.npy"),
                    "--out", os.path.join(out, "converted")], check=True)
    motions = []
    for k, (rel, start, frames) in enumerate(MOTIONS):
        m = np.load(os.path.join(fixtures, rel)).astype(np.float32)[start : start + frames]
        motions.append(m)
        with open(os.path.join(out, "motions", f"{k}.txt"), "w") as f:
            f.write(f"{rel} {start} {frames}\n")
    with open(os.path.join(out, "captions.txt"), "w") as f:
        f.write("".join(c + "#0.0#0.0\n" for c in CAPTIONS))
    np.save(os.path.join(out, "expected_motion.npy"), embed_motions(enc, mean, std, motions).astype(np.float32))
    vocab = {w: i for i, w in enumerate(words)}
    np.save(os.path.join(out, "expected_text.npy"), embed_texts(enc, vocab, vectors, CAPTIONS).astype(np.float32))
    print(f"{out}: recorded {len(motions)} motions and {len(CAPTIONS)} captions")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=["record"])
    ap.add_argument("out")
    ap.add_argument("--fixtures", required=True)
    ap.add_argument("--full-size", action="store_true", help="the real evaluator's sizes (for timing)")
    a = ap.parse_args()
    record(a.out, a.fixtures, FULL if a.full_size else SIZES)
