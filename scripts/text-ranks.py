#!/usr/bin/env python3
"""Which captions a model's motions miss: R-precision top-3 misses (text rank 3 or more) of
`diffkfc eval`'s report.json, by the caption's structure, for every row beside the real motion.

    scripts/text-ranks.py REPORT.json [--list N]

Structure, from the caption's words: "sequence" (two actions in order: then, before, after,
first), "simultaneous" (two at once: while, at the same time, and waves/raises/lifts/puts) and
"single". --list N prints the N captions missed most often by the first generated row.
"""
import argparse
import collections
import json
import re
import sys


STRUCTURES = ("single", "simultaneous", "sequence")


def structure(caption):
    if re.search(r"\b(then|before|after|first)\b", caption):
        return "sequence"
    if re.search(r"\bwhile\b|same time|\band (puts|raises|lifts|waves)\b|\bwaves\b", caption):
        return "simultaneous"
    return "single"


def fail(msg):
    """One line on stderr and exit status 2, as the other analysis scripts do."""
    print(msg, file=sys.stderr)
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.error = lambda msg: fail(f"usage: scripts/text-ranks.py REPORT.json [--list N]: {msg}")
    ap.add_argument("report")
    ap.add_argument("--list", type=int, default=0, metavar="N")
    a = ap.parse_args()
    try:
        with open(a.report) as f:
            report = json.load(f)
        first = table(report)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        fail(f"{a.report}: not a diffkfc eval report with per-item captions ({type(e).__name__}: {e})")
    for caption, n in first.most_common(a.list):
        print(f"{n}  {caption}")


def table(report):
    items = report["meta"]["items"]
    rows = []
    first = None
    for row in report["rows"]:
        ranks = row["per_item"].get("text_rank")
        if ranks is None:
            continue
        counts = collections.defaultdict(lambda: [0, 0])
        missed = collections.Counter()
        for rep, reps in enumerate(ranks):
            for it, rank in zip(items[rep], reps):
                if rank is None:
                    continue
                c = counts[structure(it["caption"])]
                c[0] += 1
                c[1] += rank >= 3
                missed[it["caption"]] += rank >= 3
        name = f"{row['name']} @ {row['keyframe_rate'] * 100:g}%"
        cells = [f"{c[0]}, {c[1] / max(c[0], 1):.3f}" for c in (counts[k] for k in STRUCTURES)]
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
        if first is None and not row["real"]:
            first = missed
    # Printed only once the whole report has been read, so a bad one prints nothing but its error.
    print("| row | " + " | ".join(f"{k}: items, top-3 misses" for k in STRUCTURES) + " |")
    print("|---|---|---|---|")
    print("\n".join(rows))
    return first or collections.Counter()


if __name__ == "__main__":
    main()
