#!/usr/bin/env bash
# One command for a lent GPU machine: the CUDA cases of the test suite, then an optional benchmark.
#
#   bash benchmarks/device_check.sh [EXTRA.py [ARGS...]]
#
# Steps, each bounded in time, each run whatever the one before gave (the summary and the exit status tell):
#  1. installs the wheels carried in .whl/ (what the machine's Python lacks: kornia, kornia_rs, colour-science,
#     colour-demosaicing; cp312 manylinux x86-64) into /tmp/site, with no index and no dependencies;
#  2. prints the GPU (nvidia-smi, queries only) and what torch sees of it, and checks that the project imports;
#  3. runs the CUDA-parametrised tests (the ``device_dtype`` fixture of tests/conftest.py: ``-k cuda``) of every
#     test file that names the fixture or CUDA, and the whole of tests/test_device_follow.py; log in
#     $OUT/cuda_tests.log;
#  4. runs EXTRA.py with ARGS (if given), log in $OUT/extra.log.
# It writes 3 files under $OUT (env.txt, cuda_tests.log, extra.log): the device tool brings back 8 at most.
# Exit status: 0 when every step that ran passed, else the first failing step's status (3: the wheels did not install;
# 4: torch sees no GPU, or the CUDA tests were skipped; others: pytest's or EXTRA.py's own; 124: a step ran out of
# its time).
#
# It changes no setting of the GPU (nvidia-smi is only queried), takes memory only through torch's allocator (no
# managed memory) and stops each step with SIGTERM, then SIGKILL, at its budget, so that nothing outlives the command.
#
# Environment (all optional):
#   OUT                        where the logs go (the device tool sets it; a fresh temporary folder elsewhere)
#   DEVICE_CHECK_PYTHON        the interpreter, words allowed (default python3: the one that holds torch there)
#   DEVICE_CHECK_WHEELS        the folder of wheels (default .whl); DEVICE_CHECK_SKIP_INSTALL=1 skips step 1
#   DEVICE_CHECK_SITE          where they go (default /tmp/site)
#   DEVICE_CHECK_NO_SMI=1      skips nvidia-smi (a dry run on a machine without a GPU)
#   DEVICE_CHECK_NO_GPU_OK=1   no GPU is not a failure (a dry run on a CPU: the CUDA tests show as skipped)
#   DEVICE_CHECK_TESTS=0       skips step 3
#   TEST_BUDGET_S              step 3's time, seconds (default 180); PER_TEST_TIMEOUT_S: one test's (default 120)
#   EXTRA_BUDGET_S             step 4's time, seconds (default 240)
set -uo pipefail
export PYTHONUNBUFFERED=1

read -ra PY <<<"${DEVICE_CHECK_PYTHON:-python3}"
OUT=${OUT:-$(mktemp -d)}
mkdir -p "$OUT"
WHEELS=${DEVICE_CHECK_WHEELS:-.whl}
SITE=${DEVICE_CHECK_SITE:-/tmp/site}
TEST_BUDGET_S=${TEST_BUDGET_S:-180}
PER_TEST_TIMEOUT_S=${PER_TEST_TIMEOUT_S:-120}
EXTRA_BUDGET_S=${EXTRA_BUDGET_S:-240}
KILL_AFTER_S=10  # grace between SIGTERM and SIGKILL when a step runs out of its time
T0=$SECONDS
status=0
summary=()

note() { summary+=("$1"); }
fail() { [ "$status" -ne 0 ] || status=$1; }
banner() { printf '\n==== %s (%ds) ====\n' "$1" $((SECONDS - T0)); }

# -- 1. the carried wheels --------------------------------------------------------------------------------------------
banner "wheels"
if [ "${DEVICE_CHECK_SKIP_INSTALL:-0}" = 1 ]; then
    note "wheels: not installed (DEVICE_CHECK_SKIP_INSTALL=1)"
elif ! compgen -G "$WHEELS/*.whl" >/dev/null; then
    note "wheels: none in $WHEELS/ (carry it: carry=[\"$WHEELS\"])"
    fail 3
else
    ls -l "$WHEELS"/*.whl
    if timeout -k "$KILL_AFTER_S" 120 "${PY[@]}" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir \
            --upgrade --target "$SITE" "$WHEELS"/*.whl; then
        export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
        note "wheels: $(ls "$WHEELS"/*.whl | wc -l) installed into $SITE"
    else
        note "wheels: the install FAILED"
        fail 3
    fi
fi
export PYTHONPATH="${PYTHONPATH:+$PYTHONPATH:}$PWD"

# -- 2. the machine ---------------------------------------------------------------------------------------------------
banner "machine"
if [ "${DEVICE_CHECK_NO_SMI:-0}" = 1 ]; then
    echo "nvidia-smi: skipped (DEVICE_CHECK_NO_SMI=1)"
else
    timeout 30 nvidia-smi --query-gpu=name,memory.total,memory.used,driver_version,temperature.gpu,utilization.gpu \
        --format=csv || echo "nvidia-smi: FAILED"
fi
timeout -k "$KILL_AFTER_S" 120 "${PY[@]}" - <<'EOF' 2>&1 | tee "$OUT/env.txt"
import importlib, platform, sys

import torch

print("python", platform.python_version(), sys.executable)
print("torch", torch.__version__, "built for CUDA", torch.version.cuda, "cuDNN", torch.backends.cudnn.version())
print("cuda available", torch.cuda.is_available(), "devices", torch.cuda.device_count())
if torch.cuda.is_available():
    p = torch.cuda.get_device_properties(0)
    print("device 0:", p.name, f"capability {p.major}.{p.minor}", f"{p.total_memory / 2**30:.1f} GiB",
          f"{p.multi_processor_count} SMs")
    x = torch.arange(4, device="cuda", dtype=torch.float64)
    assert float((x * 2).sum()) == 12.0, "a kernel on the GPU gave a wrong sum"
    torch.cuda.synchronize()
    print("a kernel ran on the GPU")
for name in ("numpy", "scipy", "skimage", "xarray", "matplotlib", "kornia", "kornia_rs", "colour", "colour_demosaicing",
             "pytest", "pytest_timeout", "xdist"):
    try:
        m = importlib.import_module(name)
        print(f"{name} {getattr(m, '__version__', '?')}")
    except Exception as exc:  # report every missing package, not only the first
        print(f"{name} MISSING ({type(exc).__name__}: {exc})")
import lenssim, pipeline, lenssim_studies, lenssim_cli.main  # noqa: E401,F401  the project imports

print("lenssim imports from", lenssim.__file__)
print("GPU", "yes" if torch.cuda.is_available() else "no")
EOF
rc=$?
gpu=$(sed -n 's/^GPU //p' "$OUT/env.txt")
if [ "$rc" -ne 0 ]; then
    note "machine: the torch/import check FAILED (status $rc; see above)"
    fail "$rc"
elif [ "$gpu" != yes ]; then
    note "machine: torch sees NO GPU"
    [ "${DEVICE_CHECK_NO_GPU_OK:-0}" = 1 ] || fail 4
else
    note "machine: $(sed -n 's/^device 0: //p' "$OUT/env.txt"), $(sed -n 's/^torch /torch /p' "$OUT/env.txt")"
fi

# -- 3. the CUDA tests ------------------------------------------------------------------------------------------------
if [ "${DEVICE_CHECK_TESTS:-1}" != 0 ]; then
    banner "CUDA tests"
    # The files that use the device_dtype fixture or name CUDA (the same tests as `-k cuda` over tests/, without
    # collecting modules that import what this machine lacks: grimp, rawpy, panel, distributed)
    mapfile -t files < <( (grep -rlE --include='test_*.py' 'device_dtype|cuda' tests; echo tests/test_device_follow.py) | sort -u)
    timeout_opt=()
    "${PY[@]}" -c "import pytest_timeout" 2>/dev/null && timeout_opt=(--timeout "$PER_TEST_TIMEOUT_S")
    timeout -k "$KILL_AFTER_S" "$TEST_BUDGET_S" "${PY[@]}" -m pytest -q -p no:cacheprovider "${timeout_opt[@]}" \
        -k "cuda or test_device_follow" "${files[@]}" 2>&1 | tee "$OUT/cuda_tests.log"
    rc=$?
    last=$(grep -E '(passed|failed|errors?|skipped|deselected|no tests ran).* in [0-9.]+s' "$OUT/cuda_tests.log" | tail -1 | tr -d '=')
    cuda_skipped=$(grep -cE 'SKIPPED .*no CUDA device' "$OUT/cuda_tests.log")
    note "CUDA tests (${#files[@]} files, -k 'cuda or test_device_follow'): status $rc,${last:- no pytest summary line}"
    [ "$rc" -eq 0 ] || fail "$rc"
    if [ "$gpu" = yes ] && [ "$cuda_skipped" -gt 0 ]; then
        note "CUDA tests: $cuda_skipped skip lines say 'no CUDA device' although torch sees one"
        fail 4
    fi
fi

# -- 4. the extra script ----------------------------------------------------------------------------------------------
if [ $# -gt 0 ]; then
    banner "extra: $*"
    timeout -k "$KILL_AFTER_S" "$EXTRA_BUDGET_S" "${PY[@]}" "$@" 2>&1 | tee "$OUT/extra.log"
    rc=$?
    note "extra ($1): status $rc"
    [ "$rc" -eq 0 ] || fail "$rc"
fi

# -- what is left on the GPU, and the summary ---------------------------------------------------------------------------
if [ "${DEVICE_CHECK_NO_SMI:-0}" != 1 ]; then
    banner "GPU after"
    timeout 30 nvidia-smi --query-gpu=memory.used,temperature.gpu,utilization.gpu --format=csv || true
    timeout 30 nvidia-smi --query-compute-apps=pid,process_name,used_memory --format=csv || true
fi
banner "summary"
printf '%s\n' "${summary[@]}"
echo "logs in $OUT; status $status; $((SECONDS - T0)) s"
exit "$status"
