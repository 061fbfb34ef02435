#!/bin/bash
# The GPU checks, for a session lent a device machine (the `device` tool; see docs/guide/install.md).
#
#   bash scripts/device_checks.sh wheels   # here: the wheels the device image lacks, into .whl/
#   bash scripts/device_checks.sh run      # there (carry .whl): install them, then run every GPU part
#
# The device image has jax with CUDA, numpy, scipy, matplotlib, xarray and h5py, but not jax-md,
# arviz or their pure-Python dependencies. Results go to $OUT (the device's return folder); each
# JSON's provenance records how long its part took.
set -o pipefail
WHEELS="jax-md==0.2.29 jraph==0.0.6.dev0 ml_collections==1.1.0 e3nn-jax==0.21.0 arviz==0.23.4
xarray-einstats==0.9.1 h5netcdf==1.8.2 platformdirs==4.14.8"
case "${1:-}" in
wheels)
    grep -qx "/.whl/" .git/info/exclude 2>/dev/null || echo "/.whl/" >>.git/info/exclude
    # shellcheck disable=SC2086
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_17_x86_64 -d .whl $WHEELS
    ;;
run)
    out=${OUT:?run this on the device machine}
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 3
    export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
    # The helium example is an entry point: the main job parts need the project installed.
    python3 -m pip install -q --no-deps --no-index --no-build-isolation -e . || exit 4
    g="python3 -m benchmarks.gpu_throughput"
    {
        nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
        $g --part gpu --fused-sizes 1000 5000 --skip-main-job --output "$out/gpu_throughput.json"
        $g --part gpu_main_job --main-job-only --main-job-timeout 90 --output "$out/gpu_throughput.json"
        $g --part cpu --cpu --quick --skip-main-job --output "$out/gpu_throughput.json"
        $g --part cpu_main_job --cpu --main-job-only --main-job-timeout 90 --output "$out/gpu_throughput.json"
        if [ "${TABLE1:-0}" = 1 ]; then
            timeout 400 python3 -m benchmarks.helium_table1 --num-particles 25000 --batch-size 5000 \
                --seeds 0 1 2 3 4 --output "$out/helium_table1.json" 2>&1 | grep -v "step/s"
        fi
    } 2>&1 | tee "$out/log.txt"
    ;;
*)
    echo "usage: bash scripts/device_checks.sh wheels|run" >&2
    exit 2
    ;;
esac
