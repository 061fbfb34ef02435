#!/usr/bin/env bash
# Set up a fresh machine for jaxabc: Debian packages (GROMACS, OpenMPI, LAMMPS) when missing,
# then the Python package with its development extras.  Safe to run again: it skips what is there.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
command -v gmx >/dev/null 2>&1 || need+=(gromacs)
command -v mpiexec >/dev/null 2>&1 || need+=(openmpi-bin)
[ -e /usr/include/x86_64-linux-gnu/openmpi ] || [ -e /usr/lib/x86_64-linux-gnu/openmpi/include ] \
  || dpkg -s libopenmpi-dev >/dev/null 2>&1 || need+=(libopenmpi-dev)
command -v lmp >/dev/null 2>&1 || need+=(lammps)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing Debian packages: ${need[*]}"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "setup: missing ${need[*]}; install them with: sudo apt-get install -y ${need[*]}" >&2
    echo "setup: (tests that need them are skipped until then)" >&2
  fi
fi

PY=${PYTHON:-python3}
"$PY" -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
# The dev extra: every optional extra (plotting, water, mpi, docs) plus pytest, pytest-timeout,
# ruff, pyright (with a Node.js wheel, so no system node is needed) and pre-commit: what .ci/run uses.
"$PY" -m pip install --quiet -e ".[dev]"
"$PY" -c "import jax, jax_md, jaxabc; from importlib.metadata import version; print('setup: jax', jax.__version__, 'jax-md', version('jax-md'), 'jaxabc', jaxabc.__version__)"
# The engine's compiled all-pairs kernel (md.lj.native): built now, not inside the first run.
"$PY" -c "import sys; from md.lj.native import main; sys.exit(main())" || true
# pyright's first run unpacks its bundled type checker; do it here, not inside the CI checks.
command -v pyright >/dev/null 2>&1 && pyright --version >/dev/null 2>&1 || echo "setup: pyright is not usable; .ci/run needs it" >&2
