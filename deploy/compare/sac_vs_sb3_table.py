"""The comparison table of deploy/compare/sac-vs-sb3.sh from its CSV (who,seed,env_steps,
mean_return): per evaluation step, each side's mean ± std (median) over seeds, U (pairs of seeds
where ours beat SB3, ties counting half) and the exact two-sided Mann-Whitney p. Markdown on
stdout. Standard library only.

Usage: python3 sac_vs_sb3_table.py CSV
"""
import csv
import itertools
import statistics as st
import sys


def u_stat(a, b):
    return sum(1.0 if x > y else 0.5 if x == y else 0.0 for x in a for y in b)


def mann_whitney(a, b):
    """U of a over b and the exact two-sided p: the share of all splits of the pooled values
    into groups of len(a) and len(b) whose U is at least as far from its mean len(a)·len(b)/2."""
    pooled, n = a + b, len(a)
    u = u_stat(a, b)
    centre = len(a) * len(b) / 2
    far = sum(
        1
        for idx in itertools.combinations(range(len(pooled)), n)
        if abs(u_stat([pooled[i] for i in idx], [pooled[i] for i in range(len(pooled)) if i not in idx]) - centre)
        >= abs(u - centre) - 1e-9
    )
    total = sum(1 for _ in itertools.combinations(range(len(pooled)), n))
    return u, far / total


def cell(v):
    if len(v) > 1:
        return f"{st.mean(v):.0f} ± {st.stdev(v):.0f} ({st.median(v):.0f})".replace("-", "−")
    return f"{v[0]:.0f}".replace("-", "−") if v else "–"


rows = list(csv.DictReader(open(sys.argv[1])))
by = {}
for r in rows:
    by.setdefault((int(r["env_steps"]), r["who"]), []).append(float(r["mean_return"]))
print("| env steps | ours: mean ± std (median) | SB3: mean ± std (median) | seeds | U (ours > SB3) | p |")
print("|---|---|---|---|---|---|")
for step in sorted({k[0] for k in by}):
    a, b = by.get((step, "ours"), []), by.get((step, "sb3"), [])
    u, p = mann_whitney(a, b) if a and b else (None, None)
    test = f"{u:g} of {len(a) * len(b)} | {p:.2f}" if u is not None else "– | –"
    print(f"| {step} | {cell(a)} | {cell(b)} | {len(a)} + {len(b)} | {test} |")
