"""Mean +- sd over seeds of the correlated-appearance steering study (``vtrack language eval --appearance-study``).

Usage: python data_tools/language_appearance_table.py OUT_seed0.json OUT_seed1.json ... > table.md
Prints a markdown table: unsteered rows, then per vector x position the test metrics at the strength chosen on
the validation contacts, their paired difference to no steering, and the strengths chosen.
"""

from __future__ import annotations

import json
import sys

import numpy as np


def main(paths: list[str]) -> None:
    runs = [json.load(open(p))["appearance_study"] for p in paths]

    def ms(vals) -> str:
        v = np.asarray(vals, float) * 100
        return f"{v.mean():.1f} +- {v.std(ddof=1) if len(v) > 1 else 0:.1f}"

    def msd(vals) -> str:
        v = np.asarray(vals, float)
        return f"{v.mean():.3f} +- {v.std(ddof=1) if len(v) > 1 else 0:.3f}"

    print(f"{len(runs)} seeds; test split, object R@1 / R@5 in %, silhouette of the Fig. 6 similarity vectors\n")
    print("| unsteered, test texts | R@1 | R@5 | instance R@1 | silhouette |")
    print("| --- | --- | --- | --- | --- |")
    for row in ("instance_appearance", "other_appearance", "no_appearance", "canonical_texts"):
        r = [x["none"][row] for x in runs]
        print(
            f"| {row} | {ms([x['r1'] for x in r])} | {ms([x['r5'] for x in r])} | "
            f"{ms([x['instance_r1'] for x in r])} | {msd([x['silhouette'] for x in r])} |"
        )
    att = [x["attention_on_appearance"] for x in runs]
    print(f"\nattention on colour / shape words: {ms(att)} %\n")
    base = [x["none"]["other_appearance"] for x in runs]
    print("| steering | chosen | R@1 | dR@1 (points) | silhouette | dsil | random >= A-N |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for pos in ("P1", "PRE", "P1W"):
        for vec in ("A-N", "A", "random"):
            key = f"{vec} {pos}"
            t = [x["test"][key] for x in runs]
            ch = "-" if vec == "random" else " / ".join(str(x["chosen_on_val"][key]) for x in runs)
            d = [a["r1"] - b["r1"] for a, b in zip(t, base, strict=True)]
            ds = [a["silhouette"] - b["silhouette"] for a, b in zip(t, base, strict=True)]
            share = " / ".join(f"{x['share_random_at_least_as_good']:.2f}" for x in t) if vec == "A-N" else ""
            print(
                f"| {key} | {ch} | {ms([x['r1'] for x in t])} | {ms(d)} | {msd([x['silhouette'] for x in t])} | "
                f"{msd(ds)} | {share} |"
            )
    g0 = [x["none"]["generation"] for x in runs]
    print("\n| generation | chosen | BLEU-1 (other refs) | dBLEU-1 | BLEU-1 tactile refs | names colour/shape |")
    print("| --- | --- | --- | --- | --- | --- |")
    print(
        f"| none | - | {ms([g['bleu1'] for g in g0])} | | {ms([g['bleu1_tactile_refs'] for g in g0])} | "
        f"{ms([g['appearance_share'] for g in g0])} |"
    )
    for pos in ("P4", "P3"):
        for vec in ("A-N", "A", "random"):
            key = f"{vec} {pos}"
            t = [x["test"][key] for x in runs]
            ch = "-" if vec == "random" else " / ".join(str(x["chosen_on_val"][key]) for x in runs)
            d = [a["bleu1"] - b["bleu1"] for a, b in zip(t, g0, strict=True)]
            print(
                f"| {key} | {ch} | {ms([x['bleu1'] for x in t])} | {ms(d)} | "
                f"{ms([x['bleu1_tactile_refs'] for x in t])} | {ms([x['appearance_share'] for x in t])} |"
            )


if __name__ == "__main__":
    main(sys.argv[1:])
