#!/usr/bin/env bash
# Builds the seed corpus of every fuzz target from the repository's golden files into
# fuzz/corpus/<target>/ (git-ignored; libFuzzer adds what it finds there): blobs from
# firmware/core/tests/fixtures and models/, wire frames from docs/protocol.md, recordings and
# tactile.csv files from data/, the importer fixtures of model-export/tests/fixtures.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
root=..
c=corpus
mkdir -p "$c"/{blob,protocol,app,upload,recording,eagle,import_safetensors,import_onnx,import_keras}

# Blobs: the golden v1 and v2 blobs (hex), the bench blob, the shipped models.
xxd -r -p "$root/firmware/core/tests/fixtures/golden_blob_v1.hex" > "$c/blob/golden_v1.bin"
xxd -r -p "$root/firmware/core/tests/fixtures/golden_blob_v2.hex" > "$c/blob/golden_v2.bin"
cp "$root/firmware/core/tests/fixtures/bench/model.bin" "$c/blob/bench.bin"
for b in "$root"/models/*/*.bin; do cp "$b" "$c/blob/$(basename "$b")"; done

# Wire frames: the examples table of docs/protocol.md. Protocol seeds: mode byte 0 (deframer)
# + the wire bytes; mode byte 1 (payload) + the COBS-decoded payload is left to the fuzzer.
# App seeds: profile byte 0, then each frame as a record `3, length, wire bytes without the
# delimiter` (the target fixes the CRC up after decoding, so mutated commands stay valid).
i=0
grep -o '`04[0-9a-f]*00`' "$root/docs/protocol.md" | tr -d '`' | while read -r hex; do
  i=$((i + 1))
  { printf '\x00'; echo "$hex" | xxd -r -p; } > "$c/protocol/doc_$i.bin"
  body=${hex%00}
  printf '%02x%02x%s' 3 $((${#body} / 2)) "$body" > "$c/app/rec_$i.hex"
  { printf '\x00'; xxd -r -p "$c/app/rec_$i.hex"; } > "$c/app/doc_$i.bin"
done
{ printf '\x00'; cat "$c"/app/rec_*.hex | xxd -r -p; } > "$c/app/all_commands.bin"
rm -f "$c"/app/rec_*.hex

# Upload sessions (fuzz_targets/upload.rs: start byte, then ops): release, begin of the 40 Hz
# blob, every chunk, commit; the same with a power cut and a second upload; from two slots at
# sequence u32::MAX − 1; a grasp start mid-upload (commit refused), release, commit; from two
# slots past 2^31, every chunk into the factory slot and no commit (a finding, now fixed).
for s in 000b000106 000b00010608 000b00010d03060b00010608 01feffffff0b00010608 \
    000b00010a06080b08 000b0002060800000408 2b3d923dffff0c000026; do
  echo "$s" | xxd -r -p > "$c/upload/session_$s.bin"
done

# Readers: a few real trials and the recordings of the tests.
n=0
for d in "$root"/data/eagle-shoal/trials/*/; do
  n=$((n + 1))
  [ "$n" -gt 4 ] && break
  head -c 3000 "$d/tactile.csv" > "$c/eagle/$(basename "$d").csv"
done
for r in $(find "$root/host-tools" "$root/tests" "$root/data" -name '*.csv' -size -64k 2>/dev/null \
    | xargs grep -l '^# slipguard-recording' 2>/dev/null | head -n 8); do
  cp "$r" "$c/recording/$(basename "$r")"
done
printf '# slipguard-recording v1\n# rate_hz: 16.7\n# unit: mN\ntime_s,c0,c1\n0,1,2\n0.0598802,3,4\n' \
  > "$c/recording/minimal.csv"
# What the monitor records (the first 150 frames of each), made with
#   slipguard replay data/eagle-shoal/trials/T --samples --script marks --release-at 137 --out T.bin
#   slipguard monitor --capture T.bin --record T.csv
cp seeds/recording/*.csv "$c/recording/"

# Importers.
f="$root/model-export/tests/fixtures"
for x in "$f"/*.safetensors "$root"/models/*/*.safetensors; do cp "$x" "$c/import_safetensors/"; done
for x in "$f"/*.onnx; do cp "$x" "$c/import_onnx/"; done
for x in "$f"/*.keras; do { printf '\x00'; cat "$x"; } > "$c/import_keras/$(basename "$x")"; done
for x in "$f"/*.h5; do { printf '\x01'; cat "$x"; } > "$c/import_keras/$(basename "$x")"; done
echo "seed corpus: $(find "$c" -type f | wc -l) files in fuzz/$c"
