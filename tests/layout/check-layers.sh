#!/usr/bin/env bash
# Fails when a lower layer includes a higher layer's header (docs/layout.md, "Who may
# include whom"). Headers are found by name, as the build finds them; a relative
# include ("../x.h") is resolved from the including file's folder.
# Usage: tests/layout/check-layers.sh [SOURCE_DIR]
set -euo pipefail
top=${1:-$(cd "$(dirname "$0")/../.." && pwd)}
cd "$top"

# The layer a path belongs to (the most specific folder first).
layer_of() {
  case "$1" in
    pipeline/core/*) echo core ;;
    pipeline/model/*) echo model ;;
    pipeline/geometry/*) echo geometry ;;
    pipeline/appearance/*) echo appearance ;;
    pipeline/calib/cv/*) echo cv ;;
    pipeline/calib/*) echo calib ;;
    pipeline/eval/*) echo eval ;;
    pipeline/export/*) echo export ;;
    pipeline/*) echo pipeline ;;
    drivers/*) echo drivers ;;
    proto/*) echo proto ;;
    sim/emu/*) echo emu ;;
    sim/*) echo sim ;;
    daemon/*) echo daemon ;;
    *) echo top ;;
  esac
}

# What each layer may include besides itself.
allowed() {
  case "$1" in
    core) echo "" ;;
    model) echo "core" ;;
    geometry) echo "core model" ;;
    appearance) echo "core model geometry" ;;
    calib) echo "core model" ;;
    cv) echo "core model calib" ;;
    eval) echo "core model geometry appearance" ;;
    export) echo "core model geometry appearance" ;;
    pipeline) echo "core model geometry appearance calib cv eval" ;;
    drivers) echo "core model" ;;
    proto) echo "core model" ;;
    emu) echo "core model" ;;
    sim) echo "core model emu" ;;
    daemon) echo "core model drivers proto" ;;
    top) echo "ANY" ;;
  esac
}

declare -A header_layer
while IFS= read -r h; do
  name=${h##*/}
  l=$(layer_of "$h")
  if [ -n "${header_layer[$name]:-}" ] && [ "${header_layer[$name]}" != "$l" ]; then
    echo "check-layers: header name $name is in two layers (${header_layer[$name]}, $l): rename one" >&2
    exit 1
  fi
  header_layer[$name]=$l
done < <(find pipeline drivers proto sim daemon -name '*.h' -o -name '*.hpp' | sort)

bad=0
checked=0
while IFS= read -r f; do
  from=$(layer_of "$f")
  ok=" $from $(allowed "$from") "
  [ "$ok" = " top ANY " ] && continue
  while IFS=: read -r line inc; do
    inc=${inc#*\"}; inc=${inc%%\"*}
    if [[ "$inc" == */* ]]; then
      to=$(layer_of "$(realpath -m --relative-to="$top" "$(dirname "$f")/$inc")")
    else
      to=${header_layer[$inc]:-}
      [ -n "$to" ] || continue          # a system or generated header
    fi
    checked=$((checked + 1))
    case "$ok" in
      *" $to "*) ;;
      *) echo "$f:$line: layer '$from' includes \"$inc\" of layer '$to' (allowed: $(allowed "$from"))"; bad=$((bad + 1)) ;;
    esac
  done < <(grep -n '^[[:space:]]*#[[:space:]]*include[[:space:]]*"' "$f" || true)
done < <(find pipeline drivers proto sim daemon -name '*.c' -o -name '*.cpp' -o -name '*.h' -o -name '*.hpp' | sort)

if [ $checked -lt 100 ]; then
  echo "check-layers: only $checked includes checked; is $top the source tree?" >&2
  exit 1
fi
if [ $bad -gt 0 ]; then
  echo "check-layers: $bad include(s) point up the layers"
  exit 1
fi
echo "check-layers: $checked includes, every one points down the layers"
