# Argument checks shared by the analysis scripts (sourced after each sets `usage`): every
# problem is one line on stderr naming the argument and the value, and exit status 2.
# shellcheck shell=bash
bin=${DIFFKFC_BIN:-${CARGO_TARGET_DIR:-target}/release/diffkfc}

die() { echo "error: $*" >&2; exit 2; }
# need_args COUNT MIN: the usage line when fewer than MIN positional arguments were given.
need_args() { [ "$1" -ge "$2" ] || { echo "$usage" >&2; exit 2; }; }
unknown_arg() { die "unknown argument '$1' ($usage)"; }
# need_path LABEL PATH: a model, run directory, config or evaluator that must exist.
need_path() { [ -e "$2" ] || die "$1 $2 does not exist"; }
# need_data LABEL DIR: a dataset written by `diffkfc data synth` (or `data prepare`).
need_data() { [ -f "$2/manifest.json" ] || die "$1 $2 has no manifest.json (diffkfc data synth --out $2)"; }
# need_count FLAG VALUE: a whole number of at least 1 (samples); need_uint: at least 0 (seeds).
need_count() { [[ "$2" =~ ^[0-9]+$ ]] && [ "$((10#$2))" -ge 1 ] || die "$1 '$2': expected a whole number of at least 1"; }
need_uint() { [[ "$2" =~ ^[0-9]+$ ]] || die "$1 '$2': expected a whole number (0 or more)"; }
need_bin() { command -v "$bin" >/dev/null || die "the binary $bin is not built (cargo build --release, or set DIFFKFC_BIN)"; }
