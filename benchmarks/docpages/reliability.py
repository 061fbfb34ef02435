"""The reliability page: the hostile-user probes, before and after, from reliability_probes.json."""

from __future__ import annotations

from collections import Counter

from benchmarks.docpages.common import load, source, table

GOOD = ("correct", "clear error")


def page_reliability() -> str:
    d = load("reliability_probes")
    if d is None:
        return "# Reliability probes\n\nNot saved yet: run `python -m benchmarks.reliability_probes --before REV`.\n"
    probes = d["probes"]
    has_before = all("before" in p for p in probes)
    rows = []
    for p in probes:
        after = p["after"]
        row = [str(p["item"]), p["what"]]
        if has_before:
            row.append(p["before"]["outcome"])
        row += [after["outcome"], _clip(after["message"])]
        rows.append(row)
    head = ["item", "probe"] + (["before"] if has_before else []) + ["after", "what the user sees now"]
    after_counts = Counter(p["after"]["outcome"] for p in probes)
    lines = [f"- after: {_counts(after_counts)}"]
    if has_before:
        before = Counter(p["before"]["outcome"] for p in probes)
        lines.insert(0, f"- before ({(d.get('before_commit') or '?')[:10]}): {_counts(before)}")
    summary = "\n".join(lines)
    return f"""# Reliability probes

Each probe is a short program a realistic but hostile user might run: a resumed run whose model
changed, two runs in one folder, Ctrl-C in the command line, a distance that is not one, a bad
seed.  Each runs in a fresh Python process and is classified by what the user sees: `correct`
(the program's own check of the answer held), `clear error` (the message names the cause; on the
command line one `jaxabc: ...` line and no traceback), `unclear error`, `traceback` or `wrong`
(a silent wrong answer).  The items are those of the trust issue (52); "before" is the same probe
on the commit before the fixes, run in the same session.

{source("reliability_probes", data=d)}

{len(probes)} probes:

{summary}

{table(head, rows)}

The probes are `benchmarks/reliability_probes.py`; each fix also has a failing-first test
(`tests/test_faults.py`, `tests/test_faults_inputs.py`, `tests/test_faults_mcse.py`,
`tests/test_cli.py`).
{_mcse_section()}"""


def _mcse_section() -> str:
    d = load("mcse_calibration")
    if d is None:
        return ""
    rows = []
    for name, by_seeds in d["cases"].items():
        for label, c in by_seeds.items():
            b, a = c["before"], c["after"]
            rows.append(
                [
                    name,
                    label.replace("_", " "),
                    f"{c['median_final_threshold']:.3g}",
                    _z(b),
                    f"{b['n_zero']} / {b['n_beyond_4_mcse']}",
                    _z(a),
                    f"{a['n_inf']} / {a['n_beyond_4_mcse']}",
                ]
            )
    head = [
        "case",
        "runs",
        "final threshold (median)",
        "rms z before",
        "before: MCSE 0 / beyond 4 MCSE",
        "rms z after",
        "after: MCSE inf / beyond 4 MCSE",
    ]
    return f"""
## Is the reported MCSE honest?

{d["problem"]}; reference: {d["reference"]}.  z = error / reported MCSE for each seed: its root
mean square should be about 1.  "Before" is Kish's `sqrt(var / ESS)` on the same runs; "after"
is `result.mcse()`, which for ABCsubsim comes from the spread between the lineages of the prior
draws (infinite, and flagged `collapsed`, when too few remain) and for APMCABC counts the
ancestors its particles share.  rms z is over the seeds with a finite MCSE.

{source("mcse_calibration", data=d)}

{table(head, rows)}
"""


def _z(stats: dict) -> str:
    return "-" if stats["rms_z"] is None else f"{stats['rms_z']:.3g} ({stats['n_finite']} finite)"


def _counts(counter: Counter) -> str:
    order = ("correct", "clear error", "unclear error", "traceback", "wrong", "hang", "not exercised")
    return ", ".join(f"{counter[k]} {k}" for k in order if counter.get(k))


def _clip(text: str, limit: int = 140) -> str:
    one = " ".join(text.split()).replace("|", "\\|")
    return one if len(one) <= limit else one[: limit - 3] + "..."
