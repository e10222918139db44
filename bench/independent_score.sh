#!/usr/bin/env bash
# independent_score.sh IMAGES_DIR OUT_DIR SESSION [SESSION ...]
#
# Scores sessions of one flight on matches none of them chose (bench/independent_score.py): COLMAP's SIFT and
# exhaustive matcher (CPU) on the original images, once per OUT_DIR (its database.db is kept and reused), then every
# session's maps on COLMAP's verified inliers. One JSON line per session, also in OUT_DIR/scores.jsonl.
#
# Environment: MAX_IMAGE_SIZE (default 1600: COLMAP's detection size, its keypoints are in original pixels either
# way), MAX_FEATURES (default 4000), THREADS (default 2), TRIM_PX (default 3, working pixels).
set -euo pipefail
[[ $# -ge 3 ]] || { echo "usage: $0 IMAGES_DIR OUT_DIR SESSION [SESSION ...]" >&2; exit 2; }
images=$1 out=$2
shift 2
command -v colmap >/dev/null || { echo "independent_score: colmap missing (apt-get install colmap)" >&2; exit 1; }
mkdir -p "$out"
db=$out/database.db
if [[ ! -e $out/matched ]]; then
  rm -f "$db"
  QT_QPA_PLATFORM=offscreen colmap feature_extractor --database_path "$db" --image_path "$images" \
    --ImageReader.single_camera 1 --SiftExtraction.use_gpu 0 \
    --SiftExtraction.max_image_size "${MAX_IMAGE_SIZE:-1600}" \
    --SiftExtraction.max_num_features "${MAX_FEATURES:-4000}" --SiftExtraction.num_threads "${THREADS:-2}" >"$out/extract.log" 2>&1
  QT_QPA_PLATFORM=offscreen colmap exhaustive_matcher --database_path "$db" --SiftMatching.use_gpu 0 --SiftMatching.num_threads "${THREADS:-2}" \
    >"$out/match.log" 2>&1
  touch "$out/matched"
fi
/usr/bin/python3 "$(dirname "$0")/independent_score.py" "$db" "$@" --trim-px "${TRIM_PX:-3}" | tee "$out/scores.jsonl"
