#!/usr/bin/env bash
# Installs what a fresh Debian 12 machine is missing: apt packages, the test
# Python venv, and the web editor's npm packages. Idempotent and quiet when
# everything is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(build-essential cmake ninja-build pkg-config libeigen3-dev libhdf5-dev
  libflatbuffers-dev flatbuffers-compiler libboost-dev nlohmann-json3-dev
  libgtest-dev libcli11-dev chromium python3-venv
  clang libclang-rt-14-dev libomp-14-dev
  libopenvdb-dev libboost-iostreams-dev libopenvdb-tools blender)
# clang, libclang-rt-14-dev (libFuzzer, ASan and UBSan runtimes) and
# libomp-14-dev (clang's OpenMP) build the fuzz targets (docs/fuzzing.md).
# libopenvdb-dev (with libboost-iostreams-dev, which its CMake module asks
# for) builds the surfaces; vdb_print (libopenvdb-tools) and Blender read
# them back in the tests and render the gallery (docs/surfaces.md).
# FLOWCLIP_HEADLESS=1 (docker/Dockerfile's server image): only what building
# the server needs, no browser, Python venv or npm packages.
if [ -n "${FLOWCLIP_HEADLESS:-}" ]; then
  APT_PACKAGES=(build-essential cmake ninja-build pkg-config libeigen3-dev libhdf5-dev
    libflatbuffers-dev flatbuffers-compiler libboost-dev nlohmann-json3-dev
    libgtest-dev libcli11-dev libopenvdb-dev libboost-iostreams-dev)
fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing apt packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# Python venv for the scripted clients and h5py checks. Debian's python, not
# pyenv's, so the venv module is the one apt installed.
VENV=build/venv
[ -n "${FLOWCLIP_HEADLESS:-}" ] && exit 0
if [ ! -x "$VENV/bin/python" ] || ! cmp -s requirements.txt "$VENV/.requirements"; then
  echo "setup: creating Python venv in $VENV"
  mkdir -p build
  /usr/bin/python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q --disable-pip-version-check -r requirements.txt
  cp requirements.txt "$VENV/.requirements"
fi

# Blender as a Python module (PyPI's bpy, with USD) in a venv of its own:
# requirements-blender.txt says why.
BLENDER_VENV=build/venv-blender
if [ ! -x "$BLENDER_VENV/bin/python" ] || ! cmp -s requirements-blender.txt "$BLENDER_VENV/.requirements"; then
  echo "setup: creating the bpy venv in $BLENDER_VENV"
  /usr/bin/python3 -m venv "$BLENDER_VENV"
  "$BLENDER_VENV/bin/pip" install -q --disable-pip-version-check -r requirements-blender.txt
  cp requirements-blender.txt "$BLENDER_VENV/.requirements"
fi

# The Python client package (clients/python, docs: clients/python/README.md),
# installed like a user's `pip install clients/python` and again whenever its
# sources or the proto/ files it packages change. No network: its build runs
# on the venv's setuptools and its dependencies are requirements.txt's pins.
PY_PACKAGE=clients/python
package_sources() {
  { ls "$PY_PACKAGE"/pyproject.toml "$PY_PACKAGE"/setup.py "$PY_PACKAGE"/README.md proto/openapi.yaml proto/*.fbs
    find "$PY_PACKAGE/flowclip" -path "$PY_PACKAGE/flowclip/wire" -prune -o -name '*.py' -print
  } | LC_ALL=C sort | xargs sha256sum
}
package_stamp=$(package_sources | sha256sum)
if [ "$package_stamp" != "$(cat "$VENV/.flowclip-package" 2>/dev/null)" ]; then
  echo "setup: installing the Python client ($PY_PACKAGE) into $VENV"
  "$VENV/bin/pip" install -q --disable-pip-version-check --no-index --no-build-isolation --no-deps \
    --force-reinstall "./$PY_PACKAGE"
  echo "$package_stamp" >"$VENV/.flowclip-package"
fi

# Web editor packages (present once web/package.json exists). Vite 8 and
# Playwright need Node.js >= 20.19; Debian 12's own nodejs is 18.
if [ -f web/package.json ]; then
  node_version=$(node -p 'process.versions.node' 2>/dev/null || echo 0)
  IFS=. read -r node_major node_minor _ <<<"$node_version"
  if [ "$node_major" -lt 20 ] || { [ "$node_major" -eq 20 ] && [ "$node_minor" -lt 19 ]; } || ! command -v npm >/dev/null; then
    echo "setup: the editor (web/) needs Node.js >= 20.19 with npm; found ${node_version/#0/none}." >&2
    echo "       Debian 12 ships 18: install Node 20 or 22 (e.g. NodeSource's nodejs package) and run make again." >&2
    exit 1
  fi
  if [ ! -d web/node_modules ] || [ web/package-lock.json -nt web/node_modules/.package-lock.json ]; then
    echo "setup: installing npm packages in web/"
    (cd web && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --loglevel=error)
  fi
fi
