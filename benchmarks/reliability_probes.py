"""Hostile-user probes of jaxabc: each a fresh process, classified by what a user would see.

Every probe is a short program a realistic user might run (a resumed run with a changed model,
two runs in one folder, Ctrl-C in the CLI, a distance that is not one, a bad seed...).  It runs in
its own Python process against a source tree, and its outcome is one of

``correct``
    the program ran and its own check of the answer held;
``clear error``
    it stopped with an error whose message names the cause (the probe's pattern matched); for the
    CLI, one line ``jaxabc: ...`` on stderr and no traceback;
``unclear error``
    it stopped, but the message does not name the cause (a broadcasting error, JAX internals);
``traceback``
    a CLI user saw a Python traceback;
``wrong``
    it ran and returned an answer its check shows wrong (the silent failure);
``not exercised``
    an interrupt probe whose run finished before the signal in every try (:data:`INTERRUPT`).

``--before PATH`` runs the same probes against another checkout (``git worktree add PATH REV``)
as well, so the page shows each probe's outcome before and after in one run.

Usage::

    python -m benchmarks.reliability_probes [--before /tmp/oldtree] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks._common import ROOT, write_result

PRELUDE = """
import functools, json, os, signal, subprocess, sys, time, warnings
from pathlib import Path
import jax, jax.numpy as jnp, numpy as np
import jaxabc
from jaxabc import checkpoint

def gauss(key, theta):
    return theta + jax.random.normal(key, theta.shape)

def shifted(key, theta, shift=0.0):
    return theta + shift + jax.random.normal(key, theta.shape)

PRIOR = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
OBS = jnp.zeros(1)
KW = dict(num_particles=100, num_steps=4, distance="euclidean", seed=2)

def check(cond, what):
    print(("OK " if cond else "WRONG ") + what)

def stop_then_resume(first, second, d1="euclidean", d2="euclidean", **extra):
    kw = dict(KW, **extra)
    kw.pop("distance")
    jaxabc.run("apmcabc", first, PRIOR, OBS, checkpoint_dir="ck", stop_after_iterations=2, distance=d1, **kw)
    return jaxabc.run("apmcabc", second, PRIOR, OBS, checkpoint_dir="ck", resume=True, distance=d2, **kw)
"""

GAUSSIAN_CONFIG = """
[model]
simulator = "jaxabc.examples:gaussian_simulate"
[prior]
names = ["mu"]
low = [-10.0]
high = [10.0]
[observed]
values = [0.0]
[algorithm]
name = "apmcabc"
num_particles = 200
num_steps = 3
distance = "euclidean"
seed = 0
[output]
folder = "out"
"""


RACE = """
import sys
import jax, jax.numpy as jnp
import jaxabc

def g(k, t):
    return t + jax.random.normal(k, t.shape)

try:
    jaxabc.run("apmcabc", g, jaxabc.Uniform([-10.0], [10.0]), jnp.zeros(1), num_particles=200, num_steps=6,
               seed=int(sys.argv[1]), executor="serial", checkpoint_dir="ck", simulator_id="g")
    print("done")
except Exception as e:
    print(type(e).__name__)
"""


#: Start a command in the background, wait for its first checkpoint in ``ex``, send it SIGINT
#: (job control on, so that the background job does not ignore SIGINT) and wait for it.  A run
#: that finished before the signal reached it (a fast machine: the steps after the first, compiled
#: one take milliseconds) was not interrupted: the probe says so (a ``RACE`` line, exit 75) and
#: :func:`_run_one` tries again, rather than classify what an uninterrupted run does.
INTERRUPT = (
    "set -m; {command} > first.log 2>&1 & pid=$!; "
    "for i in $(seq 6000); do [ -f {folder}/checkpoint.npz ] && break; sleep 0.02; done; "
    "kill -INT $pid; wait $pid; "
    "if [ $? -eq 0 ]; then echo 'RACE the run finished before the interrupt'; exit 75; fi; "
)
#: Tries of a probe whose run finished before its interrupt (see :data:`INTERRUPT`).
INTERRUPT_TRIES = 5


#: A prefix that runs a probe with SIGINT back to its default.  A process started in the
#: background of a non-interactive shell (``cmd &``, ``nohup``, a CI step) inherits SIGINT
#: ignored, and an ignored signal stays ignored through every shell and Python below it, so the
#: Ctrl-C probes would never interrupt anything.  (An exec, not ``preexec_fn``: forking a
#: process that runs JAX's threads can deadlock.)
DEFAULT_SIGINT = (
    sys.executable,
    "-c",
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execvp(sys.argv[1], sys.argv[1:])",
)


@dataclass(frozen=True)
class Probe:
    """One probe: ``code`` (Python after :data:`PRELUDE`) or ``cli`` (a shell line), and the
    pattern a clear error must match."""

    name: str
    item: int
    what: str
    code: str = ""
    cli: str = ""
    files: tuple[tuple[str, str], ...] = ()
    expect: str = ""


P = Probe
PROBES: tuple[Probe, ...] = (
    # 1. resume with a changed model
    P(
        "resume-partial",
        1,
        "resume with functools.partial(shift=0) changed to shift=5",
        code="r = stop_then_resume(functools.partial(shifted, shift=0.0), functools.partial(shifted, shift=5.0))\n"
        "check(False, f'resumed to mean {r.bayes_estimate()[0]:.2f}')",
        expect=r"shift: checkpoint 0\.0, this run 5\.0",
    ),
    P(
        "resume-closure",
        1,
        "resume with a factory closure built with another option",
        code="def make(s):\n    return lambda key, theta: theta + s + jax.random.normal(key, theta.shape)\n"
        "r = stop_then_resume(make(0.0), make(5.0))\ncheck(False, f'resumed to mean {r.bayes_estimate()[0]:.2f}')",
        expect=r"closure\.s: checkpoint 0\.0, this run 5\.0",
    ),
    P(
        "resume-lambda",
        1,
        "resume with another lambda (same qualname '<lambda>')",
        code="r = stop_then_resume(lambda k, t: t + jax.random.normal(k, t.shape), "
        "lambda k, t: t + 5.0 + jax.random.normal(k, t.shape))\ncheck(False, 'resumed')",
        expect=r"code differs",
    ),
    P(
        "resume-distance-scale",
        1,
        "resume with standardized_euclidean of another scale",
        code="from jaxabc.distances import standardized_euclidean as se\n"
        "r = stop_then_resume(gauss, gauss, se(jnp.array([1.0])), se(jnp.array([2.0])))\ncheck(False, 'resumed')",
        expect=r"scale.*checkpoint 1\.0, this run 2\.0",
    ),
    P(
        "checkpoint-unfingerprintable",
        1,
        "checkpointed run of a closure over an opaque handle, no simulator_id",
        code="def make():\n    h = object()  # a handle: neither __dict__ nor __slots__\n"
        "    def sim(key, theta):\n        assert h\n        return gauss(key, theta)\n    return sim\n"
        "sim = make()\n"
        "jaxabc.run('apmcabc', sim, PRIOR, OBS, checkpoint_dir='ck', **KW)\ncheck(False, 'accepted')",
        expect=r"cannot be fingerprinted.*simulator_id=",
    ),
    P(
        "cli-factory-options",
        1,
        "CLI: --resume after the [model] factory's options changed (shift 0 -> 5)",
        cli="jaxabc run a.toml --no-progress > /dev/null 2>&1; sed -i 's/shift = 0.0/shift = 5.0/' a.toml; "
        "jaxabc run a.toml --resume --no-progress && echo WRONG resumed",
        files=(
            (
                "a.toml",
                GAUSSIAN_CONFIG.replace(
                    'simulator = "jaxabc.examples:gaussian_simulate"',
                    'factory = "shiftsim:make"\noptions = { shift = 0.0 }',
                ),
            ),
            (
                "shiftsim.py",
                "import jax\n\ndef make(shift=0.0):\n    def simulate(key, theta):\n"
                "        return theta + shift + jax.random.normal(key, theta.shape)\n\n    return simulate\n",
            ),
        ),
        expect=r"shift|options",
    ),
    # 2. two runs in one folder
    P(
        "folder-locked",
        2,
        "a second run into a folder another process is running in",
        code="holder = subprocess.Popen([sys.executable, '-c', 'import time, sys; from jaxabc.checkpoint import "
        'FolderLock; l = FolderLock.acquire("ck"); print(1, flush=True); time.sleep(60)\'], stdout=subprocess.PIPE)\n'
        "holder.stdout.readline()\n"
        "try:\n    jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', executor='serial', **KW)\n"
        "finally:\n    holder.kill()\ncheck(False, 'ran beside the holder')",
        expect=r"in use by another run \(process \d+",
    ),
    P(
        "two-runs-race",
        2,
        "two runs started together in one folder",
        code="ps = [subprocess.Popen([sys.executable, 'race.py', str(s)], stdout=subprocess.PIPE, text=True)\n"
        "      for s in (1, 2)]\n"
        "outs = sorted(p.communicate()[0].strip() for p in ps)\n"
        "ck = checkpoint.load(Path('ck') / 'checkpoint.npz')\n"
        "check(outs == ['FolderInUse', 'done'] and 'resumable' not in ck.counters['stop_reason'], str(outs))",
        files=(("race.py", RACE),),
    ),
    P(
        "stale-tmp",
        2,
        "resume after a crash left checkpoint.npz.tmp behind (here a folder)",
        code="kw = dict(KW, executor='serial')\n"
        "full = jaxabc.run('pmcabc', gauss, PRIOR, OBS, **kw)\n"
        "jaxabc.run('pmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', stop_after_iterations=2, **kw)\n"
        "os.mkdir('ck/checkpoint.npz.tmp')\n"
        "r = jaxabc.run('pmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', resume=True, **kw)\n"
        "check(np.array_equal(r.particles, full.particles), 'resumed to the uninterrupted result')",
    ),
    # 3. the examples
    P(
        "example-rerun-after-interrupt",
        3,
        "jaxabc example helium --quick again after Ctrl-C stopped it (a checkpoint exists)",
        cli=INTERRUPT.format(command="jaxabc example helium --quick --output ex", folder="ex")
        + "jaxabc example helium --quick --output ex > /dev/null",
        expect=r"--resume.*--overwrite",
    ),
    P(
        "example-resume",
        3,
        "jaxabc example helium --quick --resume after Ctrl-C stopped it",
        cli=INTERRUPT.format(command="jaxabc example helium --quick --output ex", folder="ex")
        + "jaxabc example helium --quick --output ex --resume > /dev/null && test -f ex/result.npz && echo OK resumed",
        expect=r"OK resumed",
    ),
    # 4. tracebacks
    P(
        "cli-ctrl-c",
        4,
        "Ctrl-C during jaxabc run, after its first checkpoint",
        cli=INTERRUPT.format(command="jaxabc run slow.toml --no-progress", folder="out")
        + "cat first.log >&2; exit 130",
        files=(
            (
                "slow.toml",
                GAUSSIAN_CONFIG.replace("jaxabc.examples:gaussian_simulate", "slowsim:simulate")
                + '[executor]\nname = "serial"\n',
            ),
            (
                "slowsim.py",
                "import time, numpy as np\ndef simulate(key, theta):\n    time.sleep(0.01)\n"
                "    return np.asarray(theta, float)\n",
            ),
        ),
        expect=r"interrupted.*--resume",
    ),
    P(
        "cli-simulator-none",
        4,
        "CLI run of a simulator that returns None",
        cli="jaxabc run none.toml --no-progress",
        files=(
            (
                "none.toml",
                GAUSSIAN_CONFIG.replace("jaxabc.examples:gaussian_simulate", "nonesim:simulate")
                + '[executor]\nname = "serial"\n',
            ),
            ("nonesim.py", "def simulate(key, theta):\n    return None\n"),
        ),
        expect=r"None",
    ),
    P(
        "cli-toml-type",
        4,
        "CLI config with low = ['-10'] (a string)",
        cli="jaxabc run t.toml --no-progress",
        files=(("t.toml", GAUSSIAN_CONFIG.replace("low = [-10.0]", 'low = ["-10"]')),),
        expect=r"low",
    ),
    # 5. unknown tables and keys
    P(
        "cli-unknown-table",
        5,
        "CLI config with a misspelt [exector] table",
        cli="jaxabc run u.toml --no-progress",
        files=(("u.toml", GAUSSIAN_CONFIG + '[exector]\nname = "serial"\n'),),
        expect=r"exector.*executor",
    ),
    P(
        "cli-unknown-key",
        5,
        "CLI config with unit = [...] in [prior]",
        cli="jaxabc run k.toml --no-progress",
        files=(("k.toml", GAUSSIAN_CONFIG.replace('names = ["mu"]', 'names = ["mu"]\nunit = ["nm"]')),),
        expect=r"unit.*units",
    ),
    # 6. distances that cannot be distances
    P(
        "kl-constant-observed",
        6,
        "distance='kl' with a constant observed sample",
        code="sim = lambda k, t: t + jax.random.normal(k, (50,))\n"
        "r = jaxabc.run('apmcabc', sim, PRIOR, jnp.zeros(50), num_particles=100, num_steps=3, distance='kl')\n"
        "check(False, f'threshold {r.thresholds[-1]}')",
        expect=r"(?i)spread|constant|kl",
    ),
    P(
        "kl-one-element",
        6,
        "distance='kl' with a one-element observed",
        code="r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, num_particles=100, num_steps=3, distance='kl')\n"
        "check(False, f'threshold {r.thresholds[-1]}')",
        expect=r"(?i)one|element|kl",
    ),
    P(
        "negative-distance",
        6,
        "a user distance that returns negative values",
        code="d = lambda o, s: jnp.sum(s - o)\n"
        "r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, num_particles=100, num_steps=3, distance=d)\n"
        "check(False, f'thresholds {r.thresholds}')",
        expect=r"(?i)negative",
    ),
    # 7. honest MCSE
    P(
        "subsim-collapse",
        7,
        "ABCsubsim, N = 300, p0 = 0.2, 5 levels, seed 8: a population that collapses to one particle",
        code="r = jaxabc.run('abcsubsim', gauss, PRIOR, OBS, num_particles=300, p0=0.2, num_steps=6,\n"
        "               distance='euclidean', seed=8)\n"
        "n = len(np.unique(r.particles[:, 0]))\n"
        "m = float(np.asarray(r.mcse())[0])\n"
        "honest = n > 5 or (not np.isfinite(m) and 'collapsed' in r.summary())\n"
        "check(honest, f'{n} distinct particles, MCSE {m:.3g}')",
    ),
    # 8. smaller ones
    P(
        "tampered-result",
        8,
        "load a result.npz whose weights lost their last 3 entries",
        code="r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, **KW)\nr.save('res.npz')\n"
        "d = dict(np.load('res.npz', allow_pickle=False))\nd['weights'] = d['weights'][:-3]\nnp.savez('res.npz', **d)\n"
        "x = jaxabc.load('res.npz')\nprint(x.bayes_estimate())\ncheck(False, 'loaded')",
        expect=r"weights",
    ),
    P(
        "fused-checkpoint-other-executor",
        8,
        "a fused run's checkpoint resumed with executor='serial'",
        code="jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', stop_after_iterations=2, **KW)\n"
        "jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', resume=True, executor='serial', **KW)\n"
        "check(False, 'resumed')",
        expect=r"executor=None",
    ),
    P(
        "save-into-folder",
        8,
        "result.save(folder) on an existing folder",
        code="r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, **KW)\nos.mkdir('out')\nr.save('out')\n"
        "check(os.path.isfile('out/result.npz') and not any(p.startswith('out.') for p in os.listdir('.')), "
        "str(sorted(os.listdir('.')) + sorted(os.listdir('out'))))",
    ),
    P(
        "seed-huge",
        8,
        "seed=2**70",
        code="jaxabc.run('apmcabc', gauss, PRIOR, OBS, **dict(KW, seed=2**70))\ncheck(False, 'ran')",
        expect=r"seed",
    ),
    P(
        "seed-string",
        8,
        "seed='0'",
        code="jaxabc.run('apmcabc', gauss, PRIOR, OBS, **dict(KW, seed='0'))\ncheck(False, 'ran')",
        expect=r"seed",
    ),
    P(
        "seed-float",
        8,
        "seed=1.5",
        code="jaxabc.run('apmcabc', gauss, PRIOR, OBS, **dict(KW, seed=1.5))\ncheck(False, 'ran')",
        expect=r"seed",
    ),
    P(
        "observed-overflow",
        8,
        "observed 1e39 with dtype float32",
        code="jaxabc.run('apmcabc', gauss, PRIOR, np.array([1e39]), **KW)\ncheck(False, 'ran')",
        expect=r"(?i)observed.*float32|float32.*observed",
    ),
    P(
        "budget-below-first",
        8,
        "max_simulations=50 with 100 particles",
        code="r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, num_particles=100, max_simulations=50)\n"
        "check(r.num_simulations <= 50, f'{r.num_simulations} simulations for a budget of 50')",
        expect=r"max_simulations=50",
    ),
    P(
        "ended-run-more-steps",
        8,
        "a finished 3-step run resumed with num_steps=5",
        code="kw = dict(KW, num_steps=3)\n"
        "jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', **kw)\n"
        "r = jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck', resume=True, **dict(kw, num_steps=5))\n"
        "f = jaxabc.run('apmcabc', gauss, PRIOR, OBS, checkpoint_dir='ck2', **dict(kw, num_steps=5))\n"
        "check(len(r.thresholds) == 5 and np.array_equal(r.particles, f.particles), f'{len(r.thresholds)} steps')",
    ),
    P(
        "complex-summaries",
        8,
        "a simulator returning complex summaries",
        code="sim = lambda k, t: (t + 1j * t).astype(jnp.complex64)\n"
        "r = jaxabc.run('apmcabc', sim, PRIOR, OBS, **KW)\ncheck(False, 'ran on the real part')",
        expect=r"(?i)complex",
    ),
    P(
        "pool-recycling",
        8,
        "process pool with max_tasks_per_worker=1: is each task in a fresh process?",
        code="from jaxabc.executors.local import ProcessPoolExecutor\nfrom pidsim import simulate\n"
        "ex = ProcessPoolExecutor(max_workers=2, max_tasks_per_worker=1)\n"
        "b = ex.map(simulate, np.zeros((5, 2), np.uint32), np.zeros((5, 1)))\nex.close()\n"
        "n = len(set(b.summaries[:, 0].tolist()))\n"
        "check(n == 5, f'{n} processes for 5 tasks')",
        files=(
            (
                "pidsim.py",
                "import os\nimport numpy as np\n\ndef simulate(key, theta):\n    return np.array([os.getpid(), 0.0])\n",
            ),
        ),
        expect=r"max_tasks_per_worker",
    ),
)


def _run_one(probe: Probe, tree: Path, timeout: float) -> dict:
    """Run one probe in a fresh process against ``tree``; classify what a user would see.  A
    probe whose run finished before its interrupt is tried again, up to :data:`INTERRUPT_TRIES`
    times, then reported as ``not exercised``."""
    seconds = 0.0
    for _ in range(INTERRUPT_TRIES):
        stdout, stderr, code, took = _attempt(probe, tree, timeout)
        seconds += took
        if not any(ln.startswith("RACE") for ln in stdout.splitlines()):
            return {"seconds": round(seconds, 2), **_classify(probe, stdout, stderr, code)}
    return {
        "seconds": round(seconds, 2),
        "outcome": "not exercised",
        "message": f"the run finished before its interrupt in {INTERRUPT_TRIES} tries",
    }


def _attempt(probe: Probe, tree: Path, timeout: float) -> tuple[str, str, int | None, float]:
    """One run of a probe in a fresh folder: ``(stdout, stderr, exit code or None on timeout, seconds)``."""
    with tempfile.TemporaryDirectory() as tmp:
        for name, text in probe.files:
            (Path(tmp) / name).write_text(text)
        env = {**os.environ, "PYTHONPATH": f"{tree}{os.pathsep}{tmp}", "JAX_PLATFORMS": "cpu"}
        # The CLI of the probed tree, whatever jaxabc is installed.
        shim = Path(tmp) / "bin"
        shim.mkdir()
        (shim / "jaxabc").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m jaxabc.cli "$@"\n')
        (shim / "jaxabc").chmod(0o755)
        env["PATH"] = f"{shim}{os.pathsep}{env['PATH']}"
        if probe.cli:
            argv = ["bash", "-c", probe.cli]
        else:
            wrapped = (
                PRELUDE
                + "try:\n"
                + textwrap.indent(probe.code, "    ")
                + "\nexcept BaseException as exc:\n"
                + "    print('RAISED', type(exc).__module__ + '.' + type(exc).__qualname__, json.dumps(str(exc)))\n"
                + "    sys.exit(3)\n"
            )
            argv = [sys.executable, "-c", wrapped]
        t0 = time.perf_counter()
        try:
            out = subprocess.run(
                [*DEFAULT_SIGINT, *argv], cwd=tmp, env=env, capture_output=True, text=True, timeout=timeout
            )
            stdout, stderr, code = out.stdout, out.stderr, out.returncode
        except subprocess.TimeoutExpired:
            stdout, stderr, code = "", "", None
        seconds = time.perf_counter() - t0
    return stdout, stderr, code, seconds


def _classify(probe: Probe, stdout: str, stderr: str, code: int | None) -> dict:
    if code is None:
        return {"outcome": "hang", "message": "did not finish within the timeout"}
    lines = stdout.splitlines()
    if probe.cli:
        err = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("WARNING")]
        if "Traceback (most recent call last)" in stderr:
            return {"outcome": "traceback", "message": err[-1][:300] if err else ""}
        if any(ln.startswith("OK") for ln in lines):
            return {"outcome": "correct", "message": next(ln for ln in lines if ln.startswith("OK"))[:300]}
        if code != 0 and err:
            message = err[-1]
            clear = len([ln for ln in err if ln.startswith("jaxabc")]) >= 1 and re.search(probe.expect, message)
            return {"outcome": "clear error" if clear else "unclear error", "message": message[:300]}
        wrong = [ln for ln in lines if ln.startswith("WRONG")]
        return {"outcome": "wrong", "message": (wrong or [f"exit code {code}, no error shown"])[-1][:300]}
    raised = [ln for ln in lines if ln.startswith("RAISED ")]
    if raised:
        _, kind, text = raised[-1].split(" ", 2)
        message = json.loads(text)
        clear = bool(probe.expect) and re.search(probe.expect, message, re.DOTALL) is not None
        return {"outcome": "clear error" if clear else "unclear error", "message": f"{kind}: {message}"[:300]}
    checks = [ln for ln in lines if ln.startswith(("OK", "WRONG"))]
    if code == 0 and checks and all(ln.startswith("OK") for ln in checks):
        return {"outcome": "correct", "message": checks[-1][:300]}
    if checks:
        return {"outcome": "wrong", "message": checks[-1][:300]}
    tail = (stderr.strip().splitlines() or ["(no output)"])[-1]
    return {"outcome": "unclear error", "message": tail[:300]}


def _worktree(rev: str, folder: Path) -> Path:
    """A checkout of ``rev`` in ``folder`` (``git worktree add --detach``)."""
    subprocess.run(
        ["git", "worktree", "add", "--detach", "-f", str(folder), rev], cwd=ROOT, check=True, capture_output=True
    )
    return folder


def _resolve(rev: str) -> str | None:
    out = subprocess.run(["git", "rev-parse", rev], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() if out.returncode == 0 else None


def _probe_all(probes: list[Probe], before_tree: Path | None, timeout: float) -> list[dict]:
    rows = []
    for probe in probes:
        row = {"name": probe.name, "item": probe.item, "what": probe.what}
        row["after"] = _run_one(probe, ROOT, timeout)
        if before_tree is not None:
            row["before"] = _run_one(probe, before_tree, timeout)
        print(
            f"{probe.name:34s} {row.get('before', {}).get('outcome', '-'):14s} -> {row['after']['outcome']}", flush=True
        )
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=None, metavar="REV", help="a commit to probe as 'before' as well")
    ap.add_argument("--quick", action="store_true", help="this tree only, written under benchmarks/results/quick")
    ap.add_argument("--only", nargs="*", default=None, help="probe names to run (default: all)")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per probe")
    ap.add_argument("--output", default=None, help="result JSON (default benchmarks/results/reliability_probes.json)")
    args = ap.parse_args(argv)
    probes = [p for p in PROBES if args.only is None or p.name in args.only]
    before_tree = None
    tmp = tempfile.TemporaryDirectory()
    if args.before is not None and not args.quick:
        before_tree = _worktree(args.before, Path(tmp.name) / "before")
    try:
        rows = _probe_all(probes, before_tree, args.timeout)
    finally:
        if before_tree is not None:
            subprocess.run(["git", "worktree", "remove", "--force", str(before_tree)], cwd=ROOT, capture_output=True)
        tmp.cleanup()
    good = ("correct", "clear error")
    payload = {
        "issue": "trust, second round (issue 52)",
        "before_commit": None if before_tree is None else _resolve(args.before),
        "probes": rows,
        "counts": {
            "probes": len(rows),
            "after_good": sum(r["after"]["outcome"] in good for r in rows),
            "before_good": sum(r["before"]["outcome"] in good for r in rows) if before_tree else None,
        },
    }
    path = write_result(args.output or "reliability_probes", payload, quick=args.quick)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
