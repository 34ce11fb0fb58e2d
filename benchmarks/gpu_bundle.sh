#!/usr/bin/env bash
# A stripped Mitsuba + drjit + trimesh for a GPU machine that has neither them nor the internet
# (benchmarks/bench_gpu_render.py run). One xz tar, unpacked there into a folder put on PYTHONPATH.
#
#   benchmarks/gpu_bundle.sh OUT.tar.xz [WHEELS_DIR]
#
# WHEELS_DIR holds (or receives, by `pip download`) the cp$PY wheels of mitsuba, drjit and trimesh.
# With SITE=/path/to/site-packages the packages are copied from an installed environment instead (so the same
# stripping can be tried on this machine's Python: `SITE=.venv/lib/python3.11/site-packages KEEP_VARIANTS=...`).
#
# Why stripped: the whole transfer to the GPU machine is 64 MiB and the mitsuba wheel alone is 62 MB. What is
# kept: mitsuba's Python files, every shared library the kept modules need (their ELF NEEDED, checked at the
# end), the variant modules in KEEP_VARIANTS (cuda_ad_rgb; scalar_rgb for `--variant auto`'s last fallback),
# the plugins the twin loads (PLUGINS: found with LD_DEBUG=files on the bench press, both cases, plus the
# twin's other scene options and the llvm probe's scene) and data/srgb.coeff. Dropped: the other variants,
# headers, type stubs, tests, the IOR/sun-sky tables. shapely, manifold3d, rtree and pymeshlab are left out:
# trimesh imports them only if present and the render path never calls them (the indentation, which needs
# pymeshlab, is done here by `bench_gpu_render.py pack`).
set -euo pipefail

OUT=${1:?usage: gpu_bundle.sh OUT.tar.xz [WHEELS_DIR]}
WHEELS=${2:-/tmp/nlips-gpu-wheels}
PY=${PY:-312}
KEEP_VARIANTS=${KEEP_VARIANTS:-"cuda_ad_rgb scalar_rgb"}
PLUGINS=${PLUGINS:-"box diffuse hdrfilm merge srgb stratified uniform independent blendbsdf dielectric
  roughconductor mesh_attribute path direct point sphere perspective gaussian"}
PIP=${PIP:-pip}
SYSTEM_LIBS="libc.so.6 libm.so.6 libstdc++.so.6 libgcc_s.so.1 libpthread.so.0 libdl.so.2 libz.so.1 librt.so.1
  ld-linux-x86-64.so.2"

STAGE=$(mktemp -d)
trap 'rm -rf "$STAGE"' EXIT

if [[ -n "${SITE:-}" ]]; then
  for pkg in mitsuba drjit trimesh; do cp -a "$SITE/$pkg" "$STAGE/"; done
  cp -a "$SITE"/mitsuba-*.dist-info "$SITE"/drjit-*.dist-info "$SITE"/trimesh-*.dist-info "$STAGE/"
else
  mkdir -p "$WHEELS"
  for spec in mitsuba==3.9.1 drjit==1.5.0 trimesh==5.2.0; do
    name=${spec%%=*}
    if ! compgen -G "$WHEELS/$name-*.whl" >/dev/null; then
      "$PIP" download --no-deps --only-binary=:all: --python-version "$PY" \
        --platform manylinux_2_28_x86_64 -d "$WHEELS" "$spec"
    fi
    python3 -m zipfile -e "$(compgen -G "$WHEELS/$name-*.whl" | head -1)" "$STAGE"
  done
fi

mi="$STAGE/mitsuba"
# variants: keep the listed modules only
for mod in "$mi"/{scalar,llvm,cuda}_*.cpython-*.so; do
  base=$(basename "$mod"); variant=${base%%.cpython-*}
  [[ " $KEEP_VARIANTS " == *" $variant "* ]] || rm -f "$mod"
done
# plugins: keep the listed ones only
for so in "$mi"/plugins/*.so; do
  name=$(basename "$so" .so)
  [[ " $(echo $PLUGINS) " == *" $name "* ]] || rm -f "$so"
done
for p in $PLUGINS; do [[ -f "$mi/plugins/$p.so" ]] || { echo "gpu_bundle.sh: plugin $p missing" >&2; exit 1; }; done
# data: the sRGB coefficient table alone (rgb variants); headers, stubs, tests, docs go
find "$mi/data" -mindepth 1 -maxdepth 1 ! -name srgb.coeff -exec rm -rf {} +
rm -rf "$mi"/include "$mi"/pkgconfig "$mi"/cmake "$mi"/mitsuba_stubs "$mi"/python/test "$STAGE"/share \
  "$STAGE"/drjit/include "$STAGE"/drjit/cmake "$STAGE"/trimesh/resources/templates/viewer.zip
find "$STAGE" \( -name '*.pyi' -o -name py.typed -o -name __pycache__ -o -name tests -o -name test \) -prune \
  -exec rm -rf {} +
rm -f "$mi"/libIlmImfUtil-mitsuba.so  # needed by no kept module (checked below)
# drjit's libnanothread needs libatomic.so.1, which the wheel leaves to the system and a bare image may lack;
# a copy next to it is found through its RUNPATH ($ORIGIN)
cp -L "${LIBATOMIC:-/usr/lib/x86_64-linux-gnu/libatomic.so.1}" "$STAGE/drjit/libatomic.so.1"

# every NEEDED library of every kept ELF file is in the bundle or a system library
missing=0
while IFS= read -r -d '' elf; do
  for lib in $(readelf -d "$elf" | awk '/NEEDED/ {gsub(/[][]/, "", $NF); print $NF}'); do
    [[ " $SYSTEM_LIBS " == *" $lib "* ]] && continue
    if ! find "$STAGE" -name "$lib" | grep -q .; then echo "gpu_bundle.sh: $elf needs $lib, absent" >&2; missing=1; fi
  done
done < <(find "$STAGE" -name '*.so*' -type f -print0)
[[ $missing == 0 ]] || exit 1

mkdir -p "$(dirname "$OUT")"
tar -C "$STAGE" -cf - . | xz -T2 -9 >"$OUT.tmp"
mv "$OUT.tmp" "$OUT"
echo "$OUT: $(du -h "$OUT" | cut -f1), $(tar -tJf "$OUT" | grep -c '\.so') shared objects," \
  "variants: $(cd "$mi" && ls *.cpython-*.so | grep -E '^(scalar|llvm|cuda)_' | sed 's/\.cpython.*//' | tr '\n' ' ')"
