"""The controlled-pairs benchmark's table (benchmarks/bench_controlled_pairs.py prints it; `make
results` writes docs/results/controlled_pairs.md's from the committed scores, results/controlled_pairs/cpu/<run>.json):
one row per pair (the predicted means of both members, the verdict), then the fractions."""
from __future__ import annotations

from gspi.data.controlled_pairs import KIND_MEMBERS


def percent(value) -> str:
    return "--" if value is None else f"{100 * value:.0f} %"


def pairs_table(scores: dict) -> str:
    lines = ["| pair | kind | family | low member: roughness, metallic | high member: roughness, metallic "
             "| verdict |", "|---|---|---|---|---|---|"]
    for r in scores["pairs"]:
        low, high = KIND_MEMBERS[r["kind"]]
        cells = [f"{m} {r['roughness'][m]:.2f}, {r['metallic'][m]:.2f}" for m in (low, high)]
        if r["kind"] == "roughness":
            verdict = (f"gap {r['gap']:+.2f}: " + ("ordered, gap >= %.1f" % scores["min_gap"] if r["ordered_with_gap"]
                                                 else "ordered, gap too small" if r["ordered"] else "inverted"))
        else:
            verdict = "separated" if r["separated"] else f"not separated at {scores['threshold']}"
        lines.append(f"| {r['id']} | {r['kind']} | {r['family']} | {cells[0]} | {cells[1]} | {verdict} |")
    rough, metal = scores["roughness"], scores["metal"]
    lines += ["", f"glossy/matte pairs ordered: {percent(rough['ordered'])} of {rough['pairs']}; "
                  f"with a gap >= {scores['min_gap']}: {percent(rough['ordered_with_gap'])}",
              f"metal/dielectric pairs separated at {scores['threshold']}: {percent(metal['separated'])} "
              f"of {metal['pairs']}"]
    return "\n".join(lines)
