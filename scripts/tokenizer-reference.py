#!/usr/bin/env python3
"""Hugging Face's own token ids for the texts below (prompts, and the corners of BERT's
normalisation and word pieces), as the golden file crates/model/tests/text_encoder.rs holds our
WordPiece tokenizer to.

    pip install tokenizers
    python3 scripts/tokenizer-reference.py [TEXT_ENCODER_DIR]

TEXT_ENCODER_DIR defaults to ~/.cache/diffkfc/text-encoder (scripts/fetch-text-encoder.sh).
Writes crates/model/tests/data/tokenizer_reference.json.
"""
import json
import os
import sys

import tokenizers

root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
data = os.path.join(root, "crates/model/tests/data")
enc_dir = sys.argv[1] if len(sys.argv) > 1 else os.path.expanduser("~/.cache/diffkfc/text-encoder")
tok = tokenizers.Tokenizer.from_file(os.path.join(enc_dir, "tokenizer.json"))
tok.no_padding()
texts = [
    "a person walks forward and waves his left hand.",
    "A Person WALKS forward!!! Then... stops?",
    "a person's left-hand waves; then (slowly) stops.",
    "walks 3.5 m at 1,200 steps/min",
    "   leading and trailing   ",
    "walk\tforward\nthen\r\nstop",
    "non\u00a0breaking\u2003spaces",
    "café naïve résumé Ångström über",
    "Straße ﬁne ｗａｌｋ",
    "İstanbul ΣΊΣΥΦΟΣ",
    "человек идет вперед",
    "一个人向前走 then 跳",
    "こんにちは 안녕하세요",
    "नमस्ते شخص يمشي",
    "“walk” ‘forward’ «run» 「jump」 【kick】",
    "side-step — then back–forth … done",
    "🙂 walks ☃ ǅ",
    "ctrl\u0007walk\u0000s zero\u200bwidth \ufffdmark",
    "[CLS] walk [SEP] [MASK] [cls] [UNK]x[PAD]",
    "a" * 120 + " pneumonoultramicroscopicsilicovolcanoconiosis",
    "xqzvwk unbelievableness hyperextension",
    " ".join(["the person jumps, then turns around and walks back slowly."] * 14),
]
items = [{"text": t, "ids": tok.encode(t).ids} for t in texts]
lines = ",\n".join(json.dumps(i, ensure_ascii=False) for i in items)
with open(os.path.join(data, "tokenizer_reference.json"), "w", encoding="utf-8") as f:
    f.write(f'{{"tokenizers": "{tokenizers.__version__}", "items": [\n{lines}\n]}}\n')
print(f"{len(items)} texts, tokenizers {tokenizers.__version__}")
