#!/usr/bin/env bash
# Install and register OpenCL platforms for clrecon (run by `bash run.sh setup`).
#   tools/setup_platforms.sh [--platforms LIST] [--icd-dir DIR]
#   LIST: comma-separated, any of (default: pocl)
#     pocl      PoCL (CPU), Debian's pocl-opencl-icd: the trusted device references are
#               rendered on
#     intel     Intel's oneAPI CPU runtime: pip's intel-opencl-rt and intel-cmplr-lib-rt
#               in a venv at CACHE/intel, their wheels kept in CACHE/wheels (a second
#               set-up downloads nothing)
#     oclgrind  Oclgrind (a simulated GPU that checks every memory access), from Debian
#   CACHE: ${XDG_CACHE_HOME:-~/.cache}/clrecon.
# Registration: as root, an .icd file per platform in /etc/OpenCL/vendors (or
# $CLRECON_SYSTEM_VENDORS; PoCL's stays as Debian installs it). Not root, or with --icd-dir
# DIR: the .icd files in DIR (default CACHE/icd), PoCL's among them (when OCL_ICD_VENDORS
# is set, ocl-icd reads that folder only), and the last line on stdout is the setting that
# selects them: export OCL_ICD_VENDORS=DIR. A Debian package needs root (or sudo).
# Idempotent: nothing in place is installed or written again. Messages go to stderr.
set -euo pipefail
PY=${PYTHON:-python3}
CACHE=${XDG_CACHE_HOME:-$HOME/.cache}/clrecon
SYSTEM_VENDORS=${CLRECON_SYSTEM_VENDORS:-/etc/OpenCL/vendors}
INTEL_PKGS="intel-opencl-rt intel-cmplr-lib-rt"

say() { echo "setup: $*" >&2; }
die() { echo "setup: $*" >&2; exit 2; }

platforms=pocl
icd_dir=
while [ $# -gt 0 ]; do
  case "$1" in
    --platforms) [ $# -ge 2 ] || die "--platforms needs a list (pocl,intel,oclgrind)"
                 platforms=$2; shift 2 ;;
    --platforms=*) platforms=${1#*=}; shift ;;
    --icd-dir) [ $# -ge 2 ] || die "--icd-dir needs a folder"; icd_dir=$2; shift 2 ;;
    --icd-dir=*) icd_dir=${1#*=}; shift ;;
    -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 0 ;;
    *) die "unknown option '$1' (options: --platforms pocl,intel,oclgrind, --icd-dir DIR)" ;;
  esac
done
want_pocl=0 want_intel=0 want_oclgrind=0
IFS=, read -r -a names <<< "$platforms"
[ ${#names[@]} -gt 0 ] || die "--platforms: empty list (pocl, intel, oclgrind)"
for p in "${names[@]}"; do
  case "$p" in
    pocl) want_pocl=1 ;;
    intel) want_intel=1 ;;
    oclgrind) want_oclgrind=1 ;;
    *) die "--platforms: unknown platform '$p' (pocl, intel, oclgrind)" ;;
  esac
done

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"
  else die "need root (or sudo) to run: $*"; fi; }
installed() { dpkg-query -W -f '${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
apt_install() {
  if ! installed "$1"; then
    say "installing $1 from Debian"
    as_root apt-get update -qq
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq "$1" >/dev/null
  fi
}
pocl_icd() {  # the text of the .icd file Debian's PoCL package installs (it names the library)
  local src
  src=$(dpkg-query -L pocl-opencl-icd 2>/dev/null | grep '\.icd$' | head -n 1 || true)
  [ -n "$src" ] && [ -f "$src" ] && cat "$src"
}

# -- install; each platform's .icd text ends up in icd_<name> ----------------------------------
if [ "$want_pocl" = 1 ]; then
  apt_install pocl-opencl-icd
  icd_pocl=$(pocl_icd) || die "pocl: pocl-opencl-icd is installed but its .icd file is gone"
fi
if [ "$want_oclgrind" = 1 ]; then
  apt_install oclgrind
  icd_oclgrind=$(dpkg-query -L oclgrind | grep '/liboclgrind-rt-icd\.so$' | head -n 1 || true)
  [ -n "$icd_oclgrind" ] || die "oclgrind: Debian's package has no liboclgrind-rt-icd.so"
fi
if [ "$want_intel" = 1 ]; then
  prefix=$CACHE/intel
  wheels=$CACHE/wheels
  if [ ! -f "$prefix/lib/libintelocl.so" ]; then
    "$PY" -c "import venv, ensurepip" >/dev/null 2>&1 || apt_install python3-venv
    [ -x "$prefix/bin/python" ] || "$PY" -m venv "$prefix"
    pip=("$prefix/bin/python" -m pip)
    # from the kept wheels where they are; else download them once, then install offline
    if ! "${pip[@]}" install -q --no-index --find-links "$wheels" $INTEL_PKGS 2>/dev/null
    then
      say "intel: downloading $INTEL_PKGS into $wheels"
      "${pip[@]}" download -q -d "$wheels" $INTEL_PKGS
      "${pip[@]}" install -q --no-index --find-links "$wheels" $INTEL_PKGS
    fi
    [ -f "$prefix/lib/libintelocl.so" ] || die "intel: no libintelocl.so in $prefix/lib"
  fi
  icd_intel=$prefix/lib/libintelocl.so
fi

# -- register ----------------------------------------------------------------------------------
registered_in() { grep -qsFx -- "$2" "$1"/*.icd; }  # does an .icd of folder $1 name library $2?
write_icd() {  # folder, file name, text: written only where it differs
  local path=$1/$2
  if [ "$(cat "$path" 2>/dev/null)" != "$3" ]; then
    mkdir -p "$1"
    printf '%s\n' "$3" > "$path.tmp.$$" && mv "$path.tmp.$$" "$path"
    say "registered $path"
  fi
}
chosen=()
[ "$want_pocl" = 1 ] && chosen+=(pocl)
[ "$want_intel" = 1 ] && chosen+=(intel)
[ "$want_oclgrind" = 1 ] && chosen+=(oclgrind)

if [ -z "$icd_dir" ] && [ "$(id -u)" = 0 ]; then
  for p in "${chosen[@]}"; do
    var=icd_$p
    registered_in "$SYSTEM_VENDORS" "${!var}" || write_icd "$SYSTEM_VENDORS" "$p.icd" "${!var}"
  done
  say "platforms ${chosen[*]}: registered in $SYSTEM_VENDORS"
  if [ "$want_oclgrind" = 1 ]; then
    say "note: every OpenCL program now sees Oclgrind as a GPU, and clrecon's default device" \
        "is the first GPU: set CLRECON_DEVICE (e.g. =Portable), or register Oclgrind with" \
        "--icd-dir instead"
  fi
  exit 0
fi
if [ -z "$icd_dir" ]; then  # not root: a folder, unless the system lists them all already
  missing=0
  for p in "${chosen[@]}"; do
    var=icd_$p
    registered_in "$SYSTEM_VENDORS" "${!var}" || missing=1
  done
  if [ "$missing" = 0 ]; then
    say "platforms ${chosen[*]}: registered in $SYSTEM_VENDORS already"
    exit 0
  fi
  icd_dir=$CACHE/icd
fi
mkdir -p "$icd_dir"
icd_dir=$(cd "$icd_dir" && pwd)
if [ "$want_pocl" = 0 ]; then  # the folder replaces the system's list: PoCL belongs in it
  if icd_pocl=$(pocl_icd); then
    chosen=(pocl "${chosen[@]}")
  else
    say "note: PoCL is not installed, so these platforms have no trusted device for" \
        "references (add pocl to --platforms)"
  fi
fi
for p in "${chosen[@]}"; do
  var=icd_$p
  write_icd "$icd_dir" "$p.icd" "${!var}"
done
say "platforms ${chosen[*]}: registered in $icd_dir; select them with"
echo "export OCL_ICD_VENDORS=$icd_dir"
