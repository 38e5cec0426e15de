"""Issue 32's learned check, the arithmetic: a policy's replays at a setting and integrated 10x
finer (`selkd eval --json`), compared as the criterion says, |coarse - fine| / |fine| on the mean
return and episode length, each with the standard error of that difference (the two replays'
episodes are independent: a gap within about two of them may be the episodes' spread, not the
integration; heavy-tailed episode lengths need more than 50 episodes).

    python3 replay_gap.py row COARSE.json FINE.json NAME
        one table row (with its header) for one run's two replays
    python3 replay_gap.py seeds OUT SEEDS COARSE FINE TAG [REF]
        the table of OUT/seed-N.coarseTAG.json against OUT/seed-N.fineTAGREF.json for
        N = 1..SEEDS, with the mean over seeds; COARSE and FINE name the two settings in the
        header (e.g. "8 x 1" and "80 x 16": rapier steps x solver passes)

Used by learned-policy-fidelity.sh and replay-finer.sh.
"""
import json
import sys


def best(path):
    """The ranked actor's episodes in one `selkd eval --json` file."""
    return [a for a in json.load(open(path))["actors"] if a["best"]][0]


def mean_se(xs):
    """The mean of xs and its standard error."""
    n = len(xs)
    mu = sum(xs) / n
    var = sum((x - mu) ** 2 for x in xs) / (n - 1) if n > 1 else 0.0
    return mu, (var / n) ** 0.5


def gap(coarse, fine):
    """`gap% ± s.e.%` of two (mean, standard error) pairs, relative to the fine one."""
    (ma, sa), (mb, sb) = coarse, fine
    if not mb:
        return "n/a"
    return f"{100 * abs(ma - mb) / abs(mb):.0f}% ± {100 * (sa * sa + sb * sb) ** 0.5 / abs(mb):.0f}%"


def replays(coarse_path, fine_path):
    """(return, length, fine return, fine length), each a (mean, standard error)."""
    c, f = best(coarse_path), best(fine_path)
    return (
        mean_se(c["returns"]),
        mean_se(c["lengths"]),
        mean_se(f["returns"]),
        mean_se(f["lengths"]),
    )


def line(name, r, l, rf, lf):
    return f"| {name} | {r[0]:.0f} | {rf[0]:.0f} | {gap(r, rf)} | {l[0]:.0f} | {lf[0]:.0f} | {gap(l, lf)} |"


def main(argv):
    if argv[1:2] == ["row"] and len(argv) == 5:
        print("| run | return | finer | gap ± s.e. | length | finer | gap ± s.e. |")
        print("|---|---|---|---|---|---|---|")
        print(line(argv[4], *replays(argv[2], argv[3])))
    elif argv[1:2] == ["seeds"] and len(argv) in (7, 8):
        out, seeds, coarse_n, fine_n, tag = argv[2], int(argv[3]), argv[4], argv[5], argv[6]
        ref = argv[7] if len(argv) == 8 else ""
        print(f"| seed | return, {coarse_n} | {fine_n} | gap ± s.e. | length, {coarse_n} | {fine_n} | gap ± s.e. |")
        print("|---|---|---|---|---|---|---|")
        rows = [
            replays(f"{out}/seed-{s}.coarse{tag}.json", f"{out}/seed-{s}.fine{tag}{ref}.json")
            for s in range(1, seeds + 1)
        ]
        for s, row in enumerate(rows, 1):
            print(line(str(s), *row))

        def pooled(i):
            # The mean over seeds of each seed's mean, and its standard error.
            ms = [row[i] for row in rows]
            return sum(m for m, _ in ms) / len(ms), sum(e * e for _, e in ms) ** 0.5 / len(ms)

        print(line("mean", *(pooled(i) for i in range(4))))
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv)
