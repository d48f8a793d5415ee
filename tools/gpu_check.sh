#!/usr/bin/env bash
# The device check: on a host with an NVIDIA GPU and no package index, set OpenCL up, run the
# kernel, blur and device tests on the GPU, then both benchmarks, and print the figures the GPU
# goals name (docs/runtimes.md "GPUs"), in one run. From the repository's root:
#
#   bash tools/gpu_check.sh                 # wheels (if any) in ./.whl, figures to $OUT or /tmp/gpu_check
#
# Wheels: where pyopencl and the project's other compiled dependencies are not installed on the
# GPU host, put manylinux wheels for its Python in ./.whl first, e.g. on a machine with an index:
#   pip download --only-binary=:all: --no-deps --python-version 3.12 \
#       --platform manylinux2014_x86_64 -d .whl pyopencl pytools platformdirs siphash24 \
#       openimageio opencolorio
# Variables: WHEELS (folder), OUT (where the logs go), N_INVERT (texels, default 128M),
# BLUR_SIZE (default 4096), TESTS_S / BENCH_S (seconds per step), GPU_SPEC (the device, as
# `bdipole-cl --device` takes it; default "nvidia"), SKIP (steps to leave out, words of:
# crosscheck tests invert blur stretch), TESTS (the test files to run on the GPU).
set -u
export PYTHONUNBUFFERED=1
cd "$(dirname "$0")/.."
T0=$SECONDS
OUTD=${OUT:-/tmp/gpu_check}
mkdir -p "$OUTD"
step() { echo; echo "=== [$((SECONDS - T0)) s] $*"; }
want() { case " ${SKIP:-} " in *" $1 "*) echo "(skipped: SKIP=$SKIP)"; return 1;; esac; }

WHEELS=${WHEELS:-.whl}
if [ -d "$WHEELS" ] && ls "$WHEELS"/*.whl >/dev/null 2>&1; then
    step "installing the wheels in $WHEELS (no index)"
    python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/gpu_site \
        "$WHEELS"/*.whl || exit 3
    export PYTHONPATH=/tmp/gpu_site
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}

step "OpenCL: NVIDIA's driver registered with the ICD loader"
lib=$(ls /usr/local/nvidia/lib64/libnvidia-opencl.so.1 /usr/local/nvidia/lib/libnvidia-opencl.so.1 \
      /usr/lib/x86_64-linux-gnu/libnvidia-opencl.so.1 2>/dev/null | head -1)
[ -n "$lib" ] || lib=$(find / -xdev -name 'libnvidia-opencl.so*' 2>/dev/null | head -1)
echo "NVIDIA OpenCL library: ${lib:-none found}"
if [ -n "$lib" ] && ! grep -qs "$lib" /etc/OpenCL/vendors/*.icd; then
    mkdir -p /tmp/gpu_vendors
    echo "$lib" > /tmp/gpu_vendors/nvidia.icd
    export OCL_ICD_VENDORS=/tmp/gpu_vendors
fi
nvidia-smi -L 2>/dev/null
lscpu | grep 'Model name'
python3 -c "import pyopencl as cl; [print(p.name, p.version, [d.name for d in p.get_devices()]) for p in cl.get_platforms()]" || exit 4

GPU=${GPU_SPEC:-nvidia}
step "devices and the probe"
timeout 300 python3 -m bdipole_cl devices 2>&1 | tee "$OUTD/devices.txt"
step "crosscheck on every working device"
if want crosscheck; then
timeout 300 python3 -m bdipole_cl crosscheck --all-devices --n 100 2>&1 | tail -30 | tee "$OUTD/crosscheck.txt"
fi

step "tests on the GPU (the kernel, blur and device files)"
if want tests; then
BDIPOLE_CL_TEST_DEVICES=$GPU timeout "${TESTS_S:-420}" python3 -m pytest -q -n "$(nproc --ignore=2)" \
    -p no:cacheprovider -ra ${TESTS:-tests/test_invert.py tests/test_invert_fast.py \
    tests/test_invert_plan.py tests/test_kernels_physics.py tests/test_stability.py \
    tests/test_numerics_contract.py tests/test_contract.py tests/test_blur.py \
    tests/test_blur_fft32.py tests/test_blur_varying.py tests/test_blur_device.py \
    tests/test_device_arrays.py tests/test_device_fft.py tests/test_choice_device.py \
    tests/test_crosscheck.py tests/test_cache.py tests/test_production_files.py \
    tests/test_stretch_blur.py tests/test_stretch_near.py tests/test_stretch_device.py \
    tests/test_stretch_windows.py} \
    2>&1 | tee "$OUTD/pytest.txt" | tail -40
fi

step "inversion: host to host against NumPy's pass, the kernel against a copy"
if want invert; then
timeout "${BENCH_S:-240}" python3 tools/bench_invert.py --default-only --device "$GPU" \
    --n "${N_INVERT:-134217728}" --repeats 5 --pairs 5 2>&1 | tee "$OUTD/bench_invert.txt"
fi

step "blur: host to host and device to device, beside CuPy's fftconvolve where CuPy is here"
if want blur; then
timeout "${BENCH_S:-240}" python3 tools/bench_blur.py --device "$GPU" --size "${BLUR_SIZE:-4096}" \
    --mfp 1 4 16 --methods auto fft --repeats 3 --pairs 3 --device-arrays \
    2>&1 | tee "$OUTD/bench_blur.txt"
fi

step "stretched blur against the texture-varying blur of the same map"
if want stretch; then
timeout "${BENCH_S:-240}" python3 tools/bench_blur.py --device "$GPU" --stretch --mfp 4 \
    --repeats 3 --pairs 3 2>&1 | tee "$OUTD/bench_stretch.txt"
fi

step "the figures the goals name"
grep -h -E "^CPU|^OpenCL|widths|% copy|copy kernel|NumPy|invert_albedo|albedo_to_coeff|out=" \
    "$OUTD/bench_invert.txt" 2>/dev/null
grep -h -E "device arrays|summary|goal|^  [0-9]" "$OUTD/bench_blur.txt" "$OUTD/bench_stretch.txt" \
    2>/dev/null
grep -h -E "passed|failed" "$OUTD/pytest.txt" 2>/dev/null | tail -2
step "done"
