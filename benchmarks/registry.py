"""The one table of saved results: what writes each, its full and quick commands, and its cost.

``benchmarks/status.py`` checks every entry's provenance, ``benchmarks/regenerate.py`` reruns the
stale ones, and ``tests/test_benchmarks_repro.py`` reruns every quick command and compares its
numbers with the saved quick JSON.  A new benchmark adds one :class:`Entry` here.

Commands are run from the repository root with ``PYTHONPATH`` set to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from benchmarks._water_family import (
    FAMILY_SEEDS,
    HOLDOUT_FAMILY,
    HOLDOUT_NO_DISCREPANCY,
    PUBLISHED_BOUNDS_FAMILY,
    PUBLISHED_BOUNDS_SEEDS,
    PUBLISHED_BOUNDS_WIDER,
)
from benchmarks._water_repeats import REPEATS

__all__ = ["CACHES", "REGISTRY", "TIMING_KEYS", "VERIFICATIONS", "Entry", "by_name"]

#: Key patterns (fnmatch, on the key alone) that hold wall/CPU times, loads or rates derived from
#: them: they differ from run to run and are left out of the exact reproduction comparison.
TIMING_KEYS = (
    "*seconds*",
    "*_s",
    "*_s_mean",
    "*_s_sd",
    "*time*",
    "*per_second*",
    "*per_core*",
    "load_average*",
    "*ratio_to_lammps*",
    "*_over_jax*",
    "numpy_over_jax",
    "*fraction_of_step*",
    "cost_s",
    "*_s_parts",
    "us_per_*",
    "*_over_apmc",
)


#: JSON files under ``benchmarks/results/`` that are caches read by the scripts, not results: the
#: water validation runs are keyed by (preset, length, theta) and reused by every dataset's run.
CACHES = frozenset({"benchmarks/results/water_validation_runs.json"})

#: The ledger of quick-mode checks (``benchmarks/verify.py``): for each result whose code changed,
#: whether its quick mode still gives its saved numbers, and on which code.
VERIFICATIONS = "benchmarks/results/verifications.json"


@dataclass(frozen=True)
class Entry:
    """One saved result (or one part of a result file that several commands fill in).

    Attributes
    ----------
    name
        Unique name, ``<file stem>`` or ``<file stem>:<part>``.
    output
        Result JSON, relative to the repository root.
    full
        Command that regenerates the saved result.
    part
        Part of ``output`` this command writes (``provenance_parts`` key), or None for the whole file.
    quick, quick_output
        A quick command (at most a few minutes on 2 cores) and the JSON it writes; None when the
        entry shares another entry's quick mode or has none.
    long
        Hours-long runs (water calibrations, criticism): listed with their cost, never chosen by a
        budget under their cost.
    legacy_cost_keys
        ``/``-separated paths of wall-time fields in results written before provenance existed;
        their sum estimates the cost when the JSON records no ``cost_s``.
    estimated_cost_s
        Seconds to assume when neither a recorded cost nor legacy fields exist.
    requires
        Programs the command needs (``gmx``, ``lmp``, ``mpiexec``).
    compare_tolerance
        Relative tolerance of the quick comparison (0: exact); non-zero only where XLA's
        vectorised rounding may differ between runs, with the reason in ``note``.
    ignore_keys
        Further key patterns left out of the quick comparison (beyond :data:`TIMING_KEYS`).
    after
        Entries whose saved results this command reads: ``regenerate.py`` runs them first and
        holds this one back while any of them is not current.
    checked_by
        Entries whose quick modes run this result's code path (the same script or library code
        on smaller inputs).  When this result's code changed, a file is vouched for when one of
        their quick checks ran it on today's code and reproduced quick numbers that were made
        with this result's version of it (``status._vouch``); a result whose every changed file
        is vouched for is current without its own rerun.  Data changes are never vouched for.
    quick_inputs
        Untracked paths (caches under ``runs/``) the quick mode reads; ``verify --rebaseline``
        copies them into its worktree at the result's commit.
    resumable
        Checkpoint paths under ``runs/`` (small files, not run caches) from which the same
        command continues a run over several sittings; ``benchmarks/park.py`` carries them
        between machines through the git tree, ``regenerate.py`` restores them before the run.
    note
        What a reader of ``status`` should know.
    retired
        Empty for a kept result; else why it is no longer kept and what supersedes it.  A retired
        result's JSON and figures leave ``benchmarks/results`` (its last version stays in the git
        history), the pages stop showing it, ``regenerate`` never reruns it, and ``status`` lists it
        as ``retired`` with this reason.  Its quick mode, if any, still runs as a check that
        vouches for other results (``checked_by``).
    """

    name: str
    output: str
    full: str
    part: str | None = None
    quick: str | None = None
    quick_output: str | None = None
    long: bool = False
    legacy_cost_keys: tuple[str, ...] = ()
    estimated_cost_s: float | None = None
    requires: tuple[str, ...] = ()
    compare_tolerance: float = 0.0
    ignore_keys: tuple[str, ...] = ()
    after: tuple[str, ...] = ()
    checked_by: tuple[str, ...] = ()
    quick_inputs: tuple[str, ...] = ()
    resumable: tuple[str, ...] = ()
    note: str = ""
    retired: str = ""


R = "benchmarks/results"
_GPU_NOTE = "made on a lent GPU machine (the device tool) with the cpu parts on its own CPU"
Q = "benchmarks/results/quick"
#: Per-simulation run caches: replayed by a rerun, never read by a page, not tracked (.gitignore).
CACHE = "runs/cache"


def paper_preset_cache(kind: str, data: str) -> str:
    """Folder, relative to ``runs/``, where the paper-preset surrogate run of ``data`` keeps its
    ``kind`` (``"checkpoint"`` or ``"run_cache"``), read by ``water_misfit`` and the water page."""
    return f"cache/water_paper_preset/{kind}_{data}"


#: The tiny model choice (``water_model_choice --tiny``) that the criticism's and the paper
#: check's quick modes start from.
_TINY_MODEL_CHOICE = f"{CACHE}/water_model_choice/xray_quick_tiny"


#: The quick checks that run a water calibration's code path (script and surrogate library).
_WATER_CHECKS = ("water_simulated:robust", "surrogate_helium", "water_model_choice")


def _water_calibration(
    name: str,
    output: str,
    command: str,
    cost_s: float,
    note: str,
    quick: str | None = None,
    resumable: tuple[str, ...] = (),
) -> Entry:
    """A long GROMACS water calibration writing the ``paper``/``robust`` part ``name`` names.

    ``quick``: the options of a reproduction check (``--quick``: 5 ps runs, written under
    ``results/quick/``), whose numbers vouch for the full run when the code changes.
    """
    part = name.split(":", 1)[1]
    return Entry(
        name,
        output,
        f"python -m benchmarks.water_calibration {command}",
        part=part,
        long=True,
        estimated_cost_s=cost_s,
        requires=("gmx",),
        note=note,
        checked_by=_WATER_CHECKS,
        quick=None if quick is None else f"python -m benchmarks.water_calibration {quick} --quick",
        quick_output=None if quick is None else f"{Q}/{Path(output).name}",
        resumable=resumable,
    )


def _model_choice_variant(name: str, folder: str, options: str, cost_s: float, note: str) -> Entry:
    """A repeat of the water model choice with its own options, cache and result folders."""
    return Entry(
        name,
        f"{R}/{name}.json",
        f"python -m benchmarks.water_model_choice --data xray --workers 2 --no-progress --continue {options} "
        f"--predictive 6 --name {name} --cache-dir {CACHE}/water_model_choice/{folder} "
        f"--result-dir {R}/water_model_choice/{folder}",
        long=True,
        requires=("gmx",),
        estimated_cost_s=cost_s,
        note=note,
        checked_by=("water_model_choice", "surrogate_helium", "water_prior_range"),
    )


def _water_surrogate(data: str, statistics: str, checkpoint: str, what: str, predictive: bool = True) -> Entry:
    """A quick-preset water calibration through the GP surrogate (``--algorithm surrogate``)."""
    return _water_calibration(
        f"water_{data}_surrogate:{statistics}",
        f"{R}/water_{data}_surrogate.json",
        f"--data {data} --statistics {statistics} --algorithm surrogate "
        f"--max-simulations 300 --workers 2{' --predictive 20' if predictive else ''} "
        f"--checkpoint-dir /tmp/{checkpoint}_ckpt --no-progress",
        3600.0,
        f"{what}; resumable with --resume",
        quick=f"--data {data} --statistics {statistics} --algorithm surrogate --max-simulations 30 "
        "--surrogate-initial 16 --surrogate-holdout 6 --workers 2 --no-progress",
    )


def _water_abc(data: str) -> Entry:
    """The paper's target through the surrogate: its statistics and unscaled distance, ABC on the
    emulated statistics (``--surrogate-mode abc``), compared with the paper's final generation by
    ``water_paper_samples``; checkpoint and run cache under ``runs/cache``, so the command continues."""
    folder = f"{CACHE}/water_calibration/{data}_paper_abc"
    return _water_calibration(
        f"water_{data}_surrogate_abc:paper",
        f"{R}/water_{data}_surrogate_abc.json",
        f"--data {data} --statistics paper --algorithm surrogate "
        f"--surrogate-mode abc --max-simulations 300 --workers 2 --predictive 10 --no-progress --continue "
        f"--checkpoint-dir {folder}_checkpoint --run-cache {folder}_runs",
        3600.0,
        "the paper's target (its statistics and unscaled distance, ABC on the emulated statistics "
        "instead of the synthetic likelihood), to compare with its final generation",
    )


def _water_paper_preset(data: str) -> Entry:
    """The paper's own protocol (515 molecules, 100 ps) through the surrogate: hours of GROMACS.

    Its checkpoint and its run cache live under ``runs/cache`` (not tracked), so the same command
    continues it in a later sitting (``--continue``), replaying the finished runs of a batch that a
    sitting cut short (``--run-cache``); ``water_misfit`` keeps the finished run's surrogate state
    in the results folder.  Its checkpoint (not the run cache) is ``resumable``: ``park.py``
    carries it to the next machine where one sitting is shorter than the run.
    """
    folder = f"{R}/water_paper_preset"
    return _water_calibration(
        f"water_{data}_surrogate_paper_preset:paper",
        f"{folder}/water_{data}_surrogate.json",
        f"--data {data} --statistics paper --preset paper "
        "--algorithm surrogate --max-simulations 200 --surrogate-tolerance 0.04 --workers 2 --predictive 10 "
        f"--checkpoint-dir runs/{paper_preset_cache('checkpoint', data)} --continue "
        f"--run-cache runs/{paper_preset_cache('run_cache', data)} --out-dir {folder} --no-progress",
        36000.0,
        "the paper's preset and statistics through the GP surrogate (issue 13); spans sittings",
        resumable=(f"runs/{paper_preset_cache('checkpoint', data)}",),
    )


#: Why the TIP3P follow-ups of the model choice are retired.
_TIP3P_RETIRED = (
    "TIP3P led the model choice made before the sources' measurement errors, the wide prior and the "
    "discrepancy term (probability 0.85, interval [5e-13, 1]); the current model choice is undecided over "
    "its seeds, so the follow-ups go to TIP4P, the rule when the model choice is undecided"
)


def _retired(what: str, commit: str, file: str, superseded_by: str) -> str:
    """The ``retired`` reason of a result saved without provenance before 2026-11-23."""
    return (
        f"{what} (saved at {commit}, no provenance); superseded by {superseded_by}; last version: "
        f"`git show {commit}:benchmarks/results/{file}`"
    )


REGISTRY: tuple[Entry, ...] = (
    Entry(
        "helium_table1",
        f"{R}/helium_table1.json",
        "python -m benchmarks.helium_table1 --num-particles 25000 --batch-size 5000 --seeds 0 1 2 3 4",
        quick="python -m benchmarks.helium_table1 --quick",
        quick_output=f"{Q}/helium_table1.json",
        legacy_cost_keys=("total_wall_time_s",),
        long=True,
        note="made on a lent GPU (its JSON has the machine and the wall time); hours on 2 CPU cores",
    ),
    Entry(
        "helium_identifiability",
        f"{R}/helium_identifiability.json",
        "python -m benchmarks.helium_identifiability",
        quick="python -m benchmarks.helium_identifiability --quick",
        quick_output=f"{Q}/helium_identifiability.json",
        estimated_cost_s=600.0,
        note="no recorded time; the script's docstring says about 10 minutes on 2 cores",
    ),
    Entry(
        "helium_lammps_agreement:cpu",
        f"{R}/helium_lammps_agreement.json",
        "python -m benchmarks.helium_lammps_agreement",
        part="cpu",
        quick=f"python -m benchmarks.helium_lammps_agreement --seeds 4 --output {Q}/helium_lammps_agreement.json",
        quick_output=f"{Q}/helium_lammps_agreement.json",
        estimated_cost_s=120.0,
        requires=("lmp",),
        note="no recorded time; the script's docstring says about 1 minute",
    ),
    Entry(
        "helium_lammps_agreement:paper",
        f"{R}/helium_lammps_agreement.json",
        "python -m benchmarks.helium_lammps_agreement --preset paper --seeds 4",
        part="paper",
        estimated_cost_s=900.0,
        requires=("lmp",),
        note="no recorded time; the script's docstring says about 15 minutes on 2 cores",
        checked_by=("helium_lammps_agreement:cpu",),
    ),
    Entry(
        "coverage",
        f"{R}/coverage.json",
        "python -m benchmarks.coverage",
        quick="python -m benchmarks.coverage --quick",
        quick_output=f"{Q}/coverage.json",
        legacy_cost_keys=("cases/*/seconds",),
    ),
    Entry(
        "abc_overhead",
        f"{R}/abc_overhead.json",
        "python -m benchmarks.abc_overhead --sizes 1000 5000",
        quick=f"python -m benchmarks.abc_overhead --sizes 1000 --skip-peers --output {Q}/abc_overhead.json",
        quick_output=f"{Q}/abc_overhead.json",
        estimated_cost_s=1800.0,
        note="timings only: the quick comparison checks the rows' settings, not their times; the full "
        "command makes ELFI and pyABC virtual environments under ~/.cache/jaxabc_benchmarks (PyPI)",
    ),
    Entry(
        "surrogate_helium",
        f"{R}/surrogate_helium.json",
        "python -m benchmarks.surrogate_helium",
        quick="python -m benchmarks.surrogate_helium --quick",
        quick_output=f"{Q}/surrogate_helium.json",
        estimated_cost_s=3000.0,
        note="the GP surrogate (both modes) against APMCABC at the same budgets and at Table 1's, on five "
        "helium data sets, each against a long APMCABC reference of the same target",
    ),
    Entry(
        "surrogate_helium_noise",
        f"{R}/surrogate_helium_noise.json",
        "python -m benchmarks.surrogate_helium_noise",
        quick="python -m benchmarks.surrogate_helium_noise --quick",
        quick_output=f"{Q}/surrogate_helium_noise.json",
        estimated_cost_s=180.0,
        note="the surrogate's noise model (auto: constant or theta-dependent) against replicate runs at its "
        "helium posterior",
    ),
    # One part per problem, so that a change of jaxabc reruns the comparison a problem at a time
    # (its jaxabc cells); the peers' cells come from the saved
    # result where their code is unchanged, and the other problems' cells are kept as saved.
    *(
        Entry(
            f"surrogate_peers:{problem}",
            f"{R}/surrogate_peers.json",
            f"python -m benchmarks.surrogate_peers --problems {problem} --import-cells {R}/surrogate_peers.json "
            "--keep-other-problems",
            part=problem,
            quick="python -m benchmarks.surrogate_peers --quick" if problem == "linear" else None,
            quick_output=f"{Q}/surrogate_peers.json" if problem == "linear" else None,
            estimated_cost_s=minutes * 60.0,
            checked_by=() if problem == "linear" else ("surrogate_peers:linear",),
            note=f"GP surrogate against sbi (NPE, NLE, sequential), BOLFI and pyABC at equal budgets: the {problem} "
            "problem",
        )
        # Estimates until a part records its own: the jaxabc cells' process_wall_s per problem in
        # the saved result made at d28db451.
        for problem, minutes in (
            ("linear", 21),
            ("banana", 24),
            ("heteroscedastic", 30),
            ("correlated5", 64),
            ("correlated8", 78),
            ("banana5", 86),
            ("student", 22),
        )
    ),
    Entry(
        "surrogate_honesty",
        f"{R}/surrogate_honesty.json",
        "python -m benchmarks.surrogate_honesty",
        quick="python -m benchmarks.surrogate_honesty --quick",
        quick_output=f"{Q}/surrogate_honesty.json",
        estimated_cost_s=1800.0,
        note="does the surrogate say NOT VALIDATED when it is wrong: step, conjugate, heteroscedastic, banana",
    ),
    Entry(
        "water_misfit",
        f"{R}/water_misfit.json",
        "python -m benchmarks.water_misfit",
        estimated_cost_s=120.0,
        note="the paper-preset X-ray surrogate's observed-data misfit, from the run's final surrogate state "
        "(taken from its checkpoint under runs/cache and kept beside its result; no GROMACS)",
        checked_by=("water_model_choice", "surrogate_helium"),
        after=("water_xray_surrogate_paper_preset:paper",),
    ),
    *(
        Entry(
            f"surrogate_classifier_replay:{record}",
            f"{R}/surrogate_classifier_replay.json",
            f"python -m benchmarks.surrogate_classifier_replay --record {record}",
            part=record,
            # Estimate until a part records its cost: the first part replayed on today's code
            # (its recorded cost_s).
            estimated_cost_s=300.0,
            note=f"the success classifier scored on the runs of {made_by} (reads {R}/{record}.npz)",
            after=(made_by,),
            checked_by=("surrogate_helium",),
        )
        for record, made_by in (
            ("water_neutron_paper_surrogate", "water_neutron_surrogate:paper"),
            ("water_neutron_robust_surrogate", "water_neutron_surrogate:robust"),
            ("water_simulated_robust_surrogate", "water_simulated_surrogate:robust"),
            ("water_xray_paper_surrogate", "water_xray_surrogate:paper"),
            ("water_xray_robust_surrogate", "water_xray_surrogate:robust"),
        )
    ),
    Entry(
        "engine_throughput",
        f"{R}/engine_throughput.json",
        "python -m benchmarks.engine_throughput",
        quick=f"python -m benchmarks.engine_throughput --quick --output {Q}/engine_throughput.json",
        quick_output=f"{Q}/engine_throughput.json",
        estimated_cost_s=600.0,
        requires=("lmp",),
        note="timings: the quick comparison checks step counts and rebuild counts; run on a quiet machine",
    ),
    Entry(
        "engine_throughput_single_core",
        f"{R}/engine_throughput_single_core.json",
        "python -m benchmarks.engine_throughput --single-core --quick",
        estimated_cost_s=600.0,
        requires=("lmp",),
        note="timings on one pinned core; run on a quiet machine",
        checked_by=("engine_throughput",),
    ),
    Entry(
        "engine_throughput_small_system",
        f"{R}/engine_throughput_small_system.json",
        "python -m benchmarks.engine_throughput --small-system --main-job",
        estimated_cost_s=600.0,
        requires=("lmp",),
        note="the 32-atom CPU preset batched over parameters against LAMMPS, in system-steps per CPU "
        "second (robust to a shared machine); --baseline-tree DIR adds the speed-up over an earlier commit",
        checked_by=("engine_throughput",),
    ),
    *(
        Entry(
            f"gpu_throughput:{part}",
            f"{R}/gpu_throughput.json",
            f"python -m benchmarks.gpu_throughput --part {part}{flags}",
            part=part,
            estimated_cost_s=cost,
            requires=("nvidia-smi",),
            note=_GPU_NOTE,
            checked_by=("engine_throughput", "helium_table1"),
        )
        for part, flags, cost in (
            ("gpu", " --fused-sizes 1000 5000 --skip-main-job", 120.0),
            ("cpu", " --cpu --quick --skip-main-job", 150.0),
            ("gpu_main_job", " --main-job-only", 60.0),
            ("cpu_main_job", " --cpu --main-job-only", 60.0),
        )
    ),
    Entry(
        "imbalance:water",
        f"{R}/imbalance.json",
        "python -m benchmarks.imbalance --systems water --num 24 --workers 2",
        part="water",
        legacy_cost_keys=("systems/water/batch_wall_seconds",),
        requires=("gmx",),
        checked_by=("imbalance:helium",),
    ),
    Entry(
        "imbalance:helium",
        f"{R}/imbalance.json",
        "python -m benchmarks.imbalance --systems helium --helium-num 32",
        part="helium",
        quick="python -m benchmarks.imbalance --quick",
        quick_output=f"{Q}/imbalance.json",
        ignore_keys=("stats_all", "stats_ok", "stats_failed"),
        legacy_cost_keys=("systems/helium/wall_time_s/*", "systems/helium/compile_seconds"),
    ),
    Entry(
        "speedup:model",
        f"{R}/speedup.json",
        "python -m benchmarks.speedup --parts model --records benchmarks/results/water_neutron_robust.npz",
        part="model",
        quick="python -m benchmarks.speedup --parts model --records benchmarks/results/water_neutron_robust.npz "
        f"--reps 1 --num-particles 500 --output {Q}/speedup.json --figure {Q}/speedup.png",
        quick_output=f"{Q}/speedup.json",
        legacy_cost_keys=("model/seconds",),
        compare_tolerance=1e-12,
        note="the k-NN duration predictions (exp of a log) differ in their last digit between processes "
        "running the same commit (a verify rebaseline against a plain run): compared to 1e-12",
    ),
    Entry(
        "speedup:ranks",
        f"{R}/speedup.json",
        "python -m benchmarks.speedup --parts ranks --records benchmarks/results/water_neutron_robust.npz "
        "--ranks 1 2 4 8 16 32",
        part="ranks",
        estimated_cost_s=900.0,
        requires=("mpiexec",),
        note="no recorded time",
        checked_by=("speedup:model",),
    ),
    Entry(
        "speedup:real",
        f"{R}/speedup.json",
        "python -m benchmarks.speedup --parts real",
        part="real",
        estimated_cost_s=600.0,
        requires=("mpiexec", "gmx"),
        note="no recorded time",
        checked_by=("speedup:model",),
    ),
    Entry(
        "speedup_model_simulated_records",
        f"{R}/speedup_model_simulated_records.json",
        "python -m benchmarks.speedup --parts model --records benchmarks/results/water_simulated_robust.npz "
        "--output benchmarks/results/speedup_model_simulated_records.json "
        "--figure benchmarks/results/speedup_model_simulated_records.png",
        part="model",
        legacy_cost_keys=("model/seconds",),
        checked_by=("speedup:model",),
    ),
    Entry(
        "water_example_curves",
        f"{R}/water_example_curves.json",
        "python -m benchmarks.water_example_curves",
        quick="python -m benchmarks.water_example_curves --quick",
        quick_output=f"{Q}/water_example_curves.json",
        legacy_cost_keys=("setup/total_wall_time_s",),
        requires=("gmx",),
    ),
    # The water calibrations: their saved JSONs recorded no command; these are rebuilt from the
    # settings each entry recorded (particles, steps, workers, order, preset) and the water README.
    Entry(
        "water_simulated:robust",
        f"{R}/water_simulated.json",
        "python -m benchmarks.water_calibration --data simulated --statistics robust --workers 2 --predictive 20",
        part="robust",
        long=True,
        legacy_cost_keys=("robust/wall_time_s",),
        requires=("gmx",),
        quick="python -m benchmarks.water_calibration --quick --data simulated --statistics robust --workers 2",
        quick_output=f"{Q}/water_simulated.json",
        retired=_retired(
            "APMCABC on the quick preset, final generation of 10 particles (ESS 7.7)",
            "4bb9127",
            "water_simulated.json",
            "water_simulated_surrogate:robust (same data and preset)",
        ),
    ),
    _water_surrogate(
        "simulated", "robust", "wsur", "GP surrogate within 300 GROMACS runs (issue 13)", predictive=False
    ),
    _water_surrogate("xray", "robust", "wxsur", "X-ray g_OO through the GP surrogate within 300 GROMACS runs"),
    _water_surrogate(
        "neutron", "robust", "wnsur", "neutron g_OO/g_OH/g_HH through the GP surrogate within 300 GROMACS runs"
    ),
    _water_surrogate(
        "xray", "paper", "wxpsur", "the paper's summaries through the GP surrogate within 300 GROMACS runs"
    ),
    _water_surrogate(
        "neutron", "paper", "wnpsur", "the paper's summaries through the GP surrogate within 300 GROMACS runs"
    ),
    _water_abc("simulated"),
    _water_abc("xray"),
    _water_abc("neutron"),
    _water_paper_preset("xray"),
    Entry(
        "water_xray:robust",
        f"{R}/water_xray.json",
        "python -m benchmarks.water_calibration --data xray --statistics robust --workers 2 --predictive 20 "
        "--validation-ps 500",
        part="robust",
        long=True,
        legacy_cost_keys=("robust/wall_time_s",),
        requires=("gmx",),
        checked_by=("water_simulated:robust",),
        retired=_retired(
            "APMCABC on the quick preset, final generation of 10 particles (ESS 7.0)",
            "1a3f59f",
            "water_xray.json",
            "water_xray_surrogate:robust and, for the verdict, water_model_choice",
        ),
    ),
    Entry(
        "water_xray:paper",
        f"{R}/water_xray.json",
        "python -m benchmarks.water_calibration --data xray --statistics paper --particles 50 --workers 2 "
        "--predictive 20",
        part="paper",
        long=True,
        legacy_cost_keys=("paper/wall_time_s",),
        requires=("gmx",),
        checked_by=("water_simulated:robust",),
        retired=_retired(
            "APMCABC on the quick preset, final generation of 5 particles (ESS 3.3)",
            "1a3f59f",
            "water_xray.json",
            "water_xray_surrogate:paper (same data and preset)",
        ),
    ),
    Entry(
        "water_neutron:robust",
        f"{R}/water_neutron.json",
        "python -m benchmarks.water_calibration --data neutron --statistics robust --workers 2 --predictive 20 "
        "--validation-ps 500",
        part="robust",
        long=True,
        legacy_cost_keys=("robust/wall_time_s",),
        requires=("gmx",),
        checked_by=("water_simulated:robust",),
        retired=_retired(
            "APMCABC on the quick preset, final generation of 10 particles (ESS 8.6)",
            "81bbd14",
            "water_neutron.json",
            "water_neutron_surrogate:robust (same data and preset)",
        ),
    ),
    Entry(
        "water_neutron:paper",
        f"{R}/water_neutron.json",
        "python -m benchmarks.water_calibration --data neutron --statistics paper --particles 50 --workers 2 "
        "--predictive 20",
        part="paper",
        long=True,
        legacy_cost_keys=("paper/wall_time_s",),
        requires=("gmx",),
        checked_by=("water_simulated:robust",),
        retired=_retired(
            "APMCABC on the quick preset, final generation of 5 particles (ESS 4.6)",
            "81bbd14",
            "water_neutron.json",
            "water_neutron_surrogate:paper (same data and preset)",
        ),
    ),
    Entry(
        "criticism_water",
        f"{R}/criticism_water.json",
        "python -m benchmarks.criticism_water --data xray --base-result benchmarks/results/water_xray_robust.npz "
        "--held-out density --workers 2 --num-draws 40 --num-replicates 32 --num-gradient-replicates 12 "
        "--num-refit-iterations 2 --refit-particles 40 --refit-alpha 0.3 --refit-steps 6",
        long=True,
        legacy_cost_keys=("wall_time_s",),
        requires=("gmx",),
        quick="python -m benchmarks.criticism_water --tiny --workers 2",
        quick_output=f"{Q}/criticism_water.json",
        after=("water_xray:robust",),
        retired=_retired(
            "criticism of TIP4P at the retired APMCABC posterior of one kind of data",
            "9168cad",
            "criticism_water.json",
            "criticism_water_joint (joint X-ray data with stated errors, the model choice's posterior)",
        ),
    ),
    Entry(
        "criticism_water_neutron",
        f"{R}/criticism_water_neutron.json",
        "python -m benchmarks.criticism_water --data neutron --base-result "
        "benchmarks/results/water_neutron_robust.npz --held-out density --workers 2 --num-draws 40 "
        "--num-replicates 32 --num-gradient-replicates 12 --num-refit-iterations 2 --refit-particles 40 "
        "--refit-alpha 0.3 --refit-steps 6",
        long=True,
        legacy_cost_keys=("wall_time_s",),
        requires=("gmx",),
        after=("water_neutron:robust",),
        checked_by=("criticism_water",),
        retired=_retired(
            "criticism of TIP4P at the retired APMCABC posterior of one kind of data",
            "2e98b0f",
            "criticism_water_neutron.json",
            "criticism_water_joint (joint X-ray data with stated errors, the model choice's posterior)",
        ),
    ),
    Entry(
        "surrogate_coverage",
        f"{R}/surrogate_coverage.json",
        "python -m benchmarks.surrogate_coverage --datasets 40",
        quick="python -m benchmarks.surrogate_coverage --quick",
        quick_output=f"{Q}/surrogate_coverage.json",
        estimated_cost_s=2400.0,
        note="simulation-based calibration of the surrogate (one jaxabc.run per data set) next to "
        "jaxabc.coverage_study('apmcabc') on the same data sets",
    ),
    Entry(
        "water_model_choice",
        f"{R}/water_model_choice.json",
        "python -m benchmarks.water_model_choice --data xray --workers 2 --no-progress --continue "
        "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy --budget-per-model 60 --predictive 6",
        long=True,
        requires=("gmx",),
        quick="python -m benchmarks.water_model_choice --tiny --workers 2 --no-progress",
        quick_output=f"{Q}/water_model_choice.json",
        estimated_cost_s=4500.0,
        note="model choice over five rigid water models by surrogate evidence (up to 60 GROMACS runs each) "
        "with the sources' measurement errors, a discrepancy sd per group of summaries and epsilon x[0.6, 2.5] "
        "(TIP3P sigma x[0.95, 1.08], epsilon x[0.4, 2.5]: its posterior piled on the common box); "
        "its simulations and checkpoints are cached under runs/cache/water_model_choice (not tracked), so the "
        "same command continues an interrupted run",
    ),
    *(
        Entry(
            name,
            f"{R}/{name}.json",
            "python -m benchmarks.water_model_choice --data xray --workers 2 --no-progress --continue "
            f"--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5{flags} --budget-per-model 60 --predictive 6 "
            f"--name {name}",
            long=True,
            requires=("gmx",),
            estimated_cost_s=4500.0,
            note=f"the model choice repeated ({what}): a verdict holds only if it holds in every repeat",
            checked_by=("water_model_choice", "surrogate_helium", "water_prior_range"),
        )
        for name, flags, what in (
            ("water_model_choice_seed1", " --discrepancy --seed 1", "seed 1"),
            ("water_model_choice_seed2", " --discrepancy --seed 2", "seed 2"),
            ("water_model_choice_seed3", " --discrepancy --seed 3", "seed 3"),
            ("water_model_choice_no_discrepancy", "", "seed 0 without the discrepancy term"),
        )
    ),
    _model_choice_variant(
        "water_model_choice_seed1_budget120",
        "xray_quick_budget120_seed1",
        "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy --seed 1 --budget-per-model 120",
        6000.0,
        "the model choice of seed 1 with twice the budget (up to 120 GROMACS runs per model): in seed 1 "
        "three emulators failed validation on 60 runs and TIP3P's epsilon sat on its lower bound",
    ),
    _model_choice_variant(
        "water_model_choice_seed3_budget120",
        "xray_quick_budget120_seed3",
        "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy --seed 3 --budget-per-model 120",
        6000.0,
        "the model choice of seed 3 with twice the budget: at 60 runs per model three of five emulators failed "
        "validation in seeds 1, 2 and 3, at 120 every one validated in seed 1",
    ),
    _model_choice_variant(
        "water_model_choice_seed3_budget120_calibrated",
        "xray_quick_budget120_seed3_calibrated",
        "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy --seed 3 --budget-per-model 120 "
        "--emulator-variance calibrated",
        6000.0,
        "the model choice of seed 3 with twice the budget and the emulator's variance calibrated from its failed "
        "validations (emulator_variance='calibrated': the design keeps the runs of a second validation, which "
        "judges the scaled emulator): with the GP's own variance three of five emulators failed validation",
    ),
    *(
        _model_choice_variant(
            f"water_model_choice_calibrated_holdout_seed{seed}",
            f"xray_quick_budget120_seed{seed}_calibrated_holdout_r_oo_max2",
            "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy "
            f"--seed {seed} --budget-per-model 120 --emulator-variance calibrated --hold-out r_oo_max2_nm",
            7200.0,
            f"the model choice of seed {seed} with the calibrated emulator variance and r_oo_max2_nm held out: "
            "every lack-of-fit failure of the repeats (TIP3P, 5 of 5) is that one summary, a window maximum that "
            "jumps between the window's edges where the second shell is flat (water_emulator_failures); the "
            "calibrated variance removes most of the other failures",
        )
        for seed in FAMILY_SEEDS
    ),
    *(
        _model_choice_variant(
            name,
            f"xray_quick_budget120_seed{seed}_calibrated_holdout_r_oo_max2_published_bounds",
            "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 --discrepancy --discrepancy-bounds published "
            f"--seed {seed} --budget-per-model 120 --emulator-variance calibrated --hold-out r_oo_max2_nm",
            7200.0,
            f"the held-out family's settings, seed {seed}, with each discrepancy sd bounded by the largest misfit a "
            "published rigid model makes in its group (water_published_predictive): with the fixed bounds (D 10, "
            "hvap 20) the fit gives D, density and hvap up, and TIP3P's epsilon piles on its lower bound",
        )
        for seed, (name, _) in zip(PUBLISHED_BOUNDS_SEEDS, PUBLISHED_BOUNDS_FAMILY, strict=True)
    ),
    _model_choice_variant(
        PUBLISHED_BOUNDS_WIDER[0],
        f"xray_quick_budget120_seed{PUBLISHED_BOUNDS_WIDER[1]}_calibrated_holdout_r_oo_max2_published_bounds_sigma_x2",
        "--prior-width 0.9,1.1,0.6,2.5 --model-prior TIP3P=0.885,1.145,0.4,2.5 --discrepancy --discrepancy-bounds "
        f"published --seed {PUBLISHED_BOUNDS_WIDER[1]} --budget-per-model 120 --emulator-variance calibrated "
        "--hold-out r_oo_max2_nm",
        7200.0,
        "the published-bounds family's trusted seed with every sigma box doubled about its centre (the wider "
        "rows of its sensitivity table need simulations there); epsilon keeps its box, as in "
        "water_model_choice_sigma_x2",
    ),
    _model_choice_variant(
        HOLDOUT_NO_DISCREPANCY,
        "xray_quick_budget120_seed0_calibrated_holdout_r_oo_max2_no_discrepancy",
        "--prior-width wide --model-prior TIP3P=0.95,1.08,0.4,2.5 "
        "--seed 0 --budget-per-model 120 --emulator-variance calibrated --hold-out r_oo_max2_nm",
        7200.0,
        "seed 0 of the held-out family without the discrepancy term, every other setting equal: the "
        "with-and-without comparison on emulators that validate (water_model_choice_no_discrepancy "
        "was made at 60 runs per model with the GP's own variance, and 3 of its 5 emulators failed)",
    ),
    _model_choice_variant(
        "water_model_choice_sigma_x2",
        "xray_quick_sigma_x2",
        "--prior-width 0.9,1.1,0.6,2.5 --model-prior TIP3P=0.885,1.145,0.4,2.5 --discrepancy --budget-per-model 60",
        4500.0,
        "the model choice of seed 0 with every sigma box doubled in width about its centre (the sensitivity "
        "table's wider boxes need simulations there); epsilon keeps its box (doubled about its centre its low end "
        "would be negative; below x0.45 the quick box is not liquid at the published sigma: water_prior_range_low)",
    ),
    Entry(
        "water_emulator_failures",
        f"{R}/water_emulator_failures.json",
        "python -m benchmarks.water_emulator_failures",
        quick="python -m benchmarks.water_emulator_failures --quick",
        quick_output=f"{Q}/water_emulator_failures.json",
        estimated_cost_s=300.0,
        after=tuple(name for name, _ in REPEATS),
        note="why the model choice's emulators fail validation: checks failed, worst-predicted summaries, the "
        "quick liquid's network break, the held-out errors' tails and where they sit (each emulator refitted "
        "on its saved design), the library's calibrated emulator variance and what it does to each repeat's "
        "verdict, over the saved repeats (no GROMACS)",
    ),
    Entry(
        "water_box_sensitivity",
        f"{R}/water_box_sensitivity.json",
        "python -m benchmarks.water_box_sensitivity",
        quick="python -m benchmarks.water_box_sensitivity --quick",
        quick_output=f"{Q}/water_box_sensitivity.json",
        estimated_cost_s=30.0,
        after=(
            *(name for name, _ in (*REPEATS, *HOLDOUT_FAMILY, *PUBLISHED_BOUNDS_FAMILY)),
            "water_published_predictive",
        ),
        note="which prior moves the water model probabilities: each model's force-field box and its "
        "discrepancy bounds halved apart, and the bounds set from the published models' misfits, from "
        "the saved repeats, the held-out family and its rerun with those bounds (no GROMACS)",
    ),
    Entry(
        "water_summary_noise",
        f"{R}/water_summary_noise.json",
        "python -m benchmarks.water_summary_noise --runs 40 --workers 2",
        quick="python -m benchmarks.water_summary_noise --quick",
        quick_output=f"{Q}/water_summary_noise.json",
        requires=("gmx",),
        estimated_cost_s=1800.0,
        after=("water_model_choice",),
        note="is the water summaries' simulator noise Gaussian: 40 replicates per model at its posterior "
        "estimate, moments with bootstrap intervals, beside the held-out errors' tails",
    ),
    Entry(
        "water_published_predictive",
        f"{R}/water_published_predictive.json",
        "python -m benchmarks.water_published_predictive --data xray --runs 3 --workers 2",
        long=True,
        requires=("gmx",),
        estimated_cost_s=300.0,
        note="each water model at its published parameters on the model choice's protocol and summaries "
        "(295 K for the X-ray data), beside the measured values: the calibrated predictive's reference",
        checked_by=("water_model_paper_check", "water_simulated:robust", "water_prior_range", "water_model_choice"),
    ),
    Entry(
        "water_paper_samples",
        f"{R}/water_paper_samples.json",
        "python -m benchmarks.water_paper_samples --seeds 3 --workers 2",
        requires=("gmx",),
        quick="python -m benchmarks.water_paper_samples --quick",
        quick_output=f"{Q}/water_paper_samples.json",
        estimated_cost_s=300.0,
        after=("water_simulated_surrogate_abc", "water_xray_surrogate_abc", "water_neutron_surrogate_abc"),
        note="the paper-statistics posteriors against the paper's final generation (sample to sample), and the "
        "density at each estimate beside the paper's Table 2; reads the saved posteriors",
    ),
    Entry(
        "water_prior_range",
        f"{R}/water_prior_range.json",
        "python -m benchmarks.water_prior_range --workers 2",
        requires=("gmx",),
        quick="python -m benchmarks.water_prior_range --quick",
        quick_output=f"{Q}/water_prior_range.json",
        estimated_cost_s=900.0,
        note="every water model at its published sigma and epsilon x the wide prior's bounds (and 1, 1.6, 3): "
        "is the box still liquid water? the basis of md.water.models.WIDE_EPSILON_FACTORS",
    ),
    Entry(
        "water_prior_range_low",
        f"{R}/water_prior_range_low.json",
        "python -m benchmarks.water_prior_range --models TIP3P TIP4P --factors 0.2 0.3 0.45 --seeds 2 "
        "--long-ps 0 --workers 2 --output benchmarks/results/water_prior_range_low.json",
        requires=("gmx",),
        estimated_cost_s=210.0,
        checked_by=("water_prior_range",),
        note="below the wide prior's lower bound (epsilon x0.6), where TIP3P's posterior piles: does the liquid "
        "hold? (the same script as water_prior_range, other factors)",
    ),
    Entry(
        "water_model_paper_check",
        f"{R}/water_model_paper_check.json",
        "python -m benchmarks.water_model_paper_check --data xray --model TIP4P --workers 2",
        long=True,
        requires=("gmx",),
        quick="python -m benchmarks.water_model_paper_check --tiny --workers 2",
        quick_inputs=(_TINY_MODEL_CHOICE,),
        quick_output=f"{Q}/water_model_paper_check.json",
        estimated_cost_s=1200.0,
        note="TIP4P's model-choice posterior draws in the paper preset beside the quick one, and its "
        "published parameters; needs water_model_choice first; runs cached under "
        "runs/cache/water_model_paper_check (not tracked)",
        after=("water_model_choice",),
    ),
    Entry(
        "water_model_paper_check_tip3p",
        f"{R}/water_model_paper_check_tip3p.json",
        "python -m benchmarks.water_model_paper_check --data xray --model TIP3P --name water_model_paper_check_tip3p "
        "--workers 2",
        long=True,
        requires=("gmx",),
        estimated_cost_s=1800.0,
        note="the same paper-preset check for TIP3P; runs cached beside TIP4P's (files are named by model)",
        after=("water_model_choice",),
        checked_by=("water_model_paper_check",),
        retired=_TIP3P_RETIRED
        + "; last version: `git show f74f268:benchmarks/results/water_model_paper_check_tip3p.json`",
    ),
    Entry(
        "criticism_water_joint",
        f"{R}/criticism_water_joint.json",
        "python -m benchmarks.criticism_water_joint --data xray --model TIP4P --workers 2 "
        f"--cache-dir {CACHE}/criticism_water_joint/xray_quick",
        long=True,
        requires=("gmx",),
        quick="python -m benchmarks.criticism_water_joint --tiny --workers 2",
        quick_output=f"{Q}/criticism_water_joint.json",
        quick_inputs=(_TINY_MODEL_CHOICE,),
        estimated_cost_s=7200.0,
        note="criticism of TIP4P on the joint data, surrogate refits; needs "
        "water_model_choice first; its simulations are cached under runs/cache/criticism_water_joint "
        "(not tracked), so the same command continues an interrupted run",
        after=("water_model_choice",),
    ),
    Entry(
        "criticism_water_joint_tip3p",
        f"{R}/criticism_water_joint_tip3p.json",
        "python -m benchmarks.criticism_water_joint --data xray --model TIP3P --name criticism_water_joint_tip3p "
        f"--workers 2 --cache-dir {CACHE}/criticism_water_joint/xray_quick",
        long=True,
        requires=("gmx",),
        estimated_cost_s=4000.0,
        note="the same criticism of TIP3P; its simulations share the TIP4P criticism's cache folder",
        after=("water_model_choice",),
        checked_by=("criticism_water_joint",),
        retired=_TIP3P_RETIRED
        + "; last version: `git show 9a06d89:benchmarks/results/criticism_water_joint_tip3p.json`",
    ),
    Entry(
        "criticism_water_joint_no_discrepancy",
        f"{R}/criticism_water_joint_no_discrepancy.json",
        "python -m benchmarks.criticism_water_joint --data xray --model TIP4P --model-choice-result "
        "water_model_choice_no_discrepancy --name criticism_water_joint_no_discrepancy --workers 2 "
        f"--cache-dir {CACHE}/criticism_water_joint/xray_quick",
        long=True,
        requires=("gmx",),
        estimated_cost_s=7200.0,
        note="the criticism of TIP4P started from the model choice without the discrepancy term; its "
        "simulations share the criticism's cache folder",
        after=("water_model_choice_no_discrepancy",),
        checked_by=("criticism_water_joint",),
    ),
    Entry(
        "criticism_water_joint_published_bounds",
        f"{R}/criticism_water_joint_published_bounds.json",
        "python -m benchmarks.criticism_water_joint --data xray --model TIP4P --model-choice-result "
        f"{PUBLISHED_BOUNDS_FAMILY[1][0]} --name criticism_water_joint_published_bounds --workers 2 "
        f"--cache-dir {CACHE}/criticism_water_joint/xray_quick",
        long=True,
        requires=("gmx",),
        estimated_cost_s=7200.0,
        note="the criticism of TIP4P (the model choice is undecided) started from the published-bounds family's "
        "seed 1, its first seed with every emulator validated; its simulations share the criticism's cache folder",
        after=(PUBLISHED_BOUNDS_FAMILY[1][0],),
        checked_by=("criticism_water_joint",),
    ),
    Entry(
        "water_density_relaxation",
        f"{R}/water_density_relaxation.json",
        "python -m benchmarks.water_density_relaxation --workers 2",
        quick="python -m benchmarks.water_density_relaxation --quick",
        quick_output=f"{Q}/water_density_relaxation.json",
        estimated_cost_s=1100.0,
        requires=("gmx",),
        note="quick preset: analysed-window density against an extended tail at TIP4P and 8 prior corners",
    ),
    Entry(
        "water_jaxmd_speed",
        f"{R}/water_jaxmd_speed.json",
        "python -m benchmarks.water_jaxmd_speed",
        requires=("gmx",),
        note="timings of the jax-md TIP4P engine against GROMACS on one core; run on a quiet machine",
        checked_by=("water_jaxmd_density",),
    ),
    Entry(
        "water_jaxmd_density",
        f"{R}/water_jaxmd_density.json",
        "python -m benchmarks.water_jaxmd_density",
        quick="python -m benchmarks.water_jaxmd_density --quick",
        quick_output=f"{Q}/water_jaxmd_density.json",
        estimated_cost_s=1000.0,
        requires=("gmx",),
        note="NPT density and U/N: jax-md Monte Carlo barostat against GROMACS C-rescale, same state point",
    ),
    Entry(
        "water_jaxmd_agreement",
        f"{R}/water_jaxmd_agreement.json",
        "python -m benchmarks.water_jaxmd_agreement",
        long=True,
        estimated_cost_s=2700.0,
        requires=("gmx",),
        note="NVT, fixed box: U/N, S1..S9 over seeds; the NPT density is water_jaxmd_density",
        checked_by=("water_jaxmd_density",),
    ),
    Entry(
        "water_jaxmd_agreement_1fs",
        f"{R}/water_jaxmd_agreement_1fs.json",
        "python -m benchmarks.water_jaxmd_agreement --timestep-ps 0.001 --output water_jaxmd_agreement_1fs",
        long=True,
        estimated_cost_s=1800.0,
        requires=("gmx",),
        note="the agreement at 1 fs: separates the integrators' time-step error from the model",
        checked_by=("water_jaxmd_density",),
    ),
    Entry(
        "criticism_neon",
        f"{R}/criticism_neon.json",
        "python -m benchmarks.criticism_neon",
        long=True,
        estimated_cost_s=2400.0,
        note="smoke run of the plumbing: python -m benchmarks.criticism_neon --tiny (numbers meaningless)",
        checked_by=("criticism_water", "helium_table1", "criticism_argon_b2", "criticism_neon_b2", "surrogate_helium"),
    ),
    Entry(
        "criticism_neon_b2",
        f"{R}/criticism_neon_b2.json",
        "python -m benchmarks.criticism_b2 --fluid neon",
        quick="python -m benchmarks.criticism_b2 --fluid neon --quick",
        quick_output=f"{Q}/criticism_neon_b2.json",
        estimated_cost_s=600.0,
        note="neon B2 with a reference pair potential held within a box: power and the fh_scale refit",
    ),
    Entry(
        "criticism_argon_b2",
        f"{R}/criticism_argon_b2.json",
        "python -m benchmarks.criticism_b2 --fluid argon",
        quick="python -m benchmarks.criticism_b2 --fluid argon --quick",
        quick_output=f"{Q}/criticism_argon_b2.json",
        estimated_cost_s=120.0,
        note="LJ argon B2 with the Mie exponent in the catalogue: the pair shape named",
    ),
    Entry(
        "criticism_argon",
        f"{R}/criticism_argon.json",
        "python -m benchmarks.criticism_neon --fluid argon",
        long=True,
        estimated_cost_s=3000.0,
        checked_by=("criticism_water", "helium_table1", "criticism_argon_b2", "criticism_neon_b2", "surrogate_helium"),
    ),
    Entry(
        "mcse_calibration",
        f"{R}/mcse_calibration.json",
        "python -m benchmarks.mcse_calibration",
        quick="python -m benchmarks.mcse_calibration --quick",
        quick_output=f"{Q}/mcse_calibration.json",
        estimated_cost_s=300.0,
        note="z = error / reported MCSE over seeds, against the exact ABC-posterior mean (0 by symmetry)",
    ),
    Entry(
        "reliability_probes",
        f"{R}/reliability_probes.json",
        "python -m benchmarks.reliability_probes --before 439269f",
        quick="python -m benchmarks.reliability_probes --quick",
        quick_output=f"{Q}/reliability_probes.json",
        estimated_cost_s=900.0,
        ignore_keys=("message",),
        note="hostile-user probes, each in a fresh process, before (439269f) and after the trust fixes; "
        "messages hold process ids and temporary paths, so the quick comparison checks the outcomes",
    ),
)


def by_name(name: str) -> Entry:
    """The entry called ``name``; ``KeyError`` listing the known names otherwise."""
    for entry in REGISTRY:
        if entry.name == name:
            return entry
    raise KeyError(f"no benchmark {name!r}; known: {', '.join(e.name for e in REGISTRY)}")
