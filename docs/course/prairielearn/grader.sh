#!/usr/bin/env bash
# PrairieLearn's external grader for an assignment kept on a raytile grading service
# (docs/grading.md, section 10). PrairieLearn runs it in the question's image with the
# student's files in /grade/student and reads /grade/results/results.json, which
# `raytile submit` writes whatever happens (a service that cannot be reached gives
# `gradable: false`: the student loses no attempt).
#
# Settings come from the question's info.json (externalGradingOptions.environment):
# RAYTILE_SERVER, RAYTILE_TOKEN (a grader token for the assignment), RAYTILE_ASSIGNMENT.
# The student uploads an executable `render`: `render SCENE.json OUT.png` writes the
# image, `render SCENE.json OUT.npy` the hit data.
set -u
ROOT="${PL_GRADE_ROOT:-/grade}"

# PrairieLearn keeps the grade and does not tell an external grader who submitted:
# each submission is recorded under an id of its own (see docs/grading.md).
STUDENT="${RAYTILE_STUDENT:-pl-$(date +%s)-$$-$RANDOM}"

WORK=$(mktemp -d)
mkdir -p "$ROOT/results" "$WORK/out" "$WORK/logs"
cd "$ROOT/student" || exit 1
[ -x render ] || chmod +x render 2>/dev/null

if raytile scenes --server "$RAYTILE_SERVER" --assignment "$RAYTILE_ASSIGNMENT" \
  --deadline 60 -o "$WORK/scenes" >"$WORK/scenes.tsv"; then
  while IFS=$'\t' read -r name grade path; do
    case "$grade" in
      image) exts="png" ;;
      hits) exts="npy" ;;
      *) exts="png npy" ;;
    esac
    for ext in $exts; do
      timeout 120 ./render "$path" "$WORK/out/$name.$ext" >"$WORK/logs/$name.$ext.log" 2>&1 ||
        echo "render $name.$ext failed: see the scene's report"
    done
  done <"$WORK/scenes.tsv"
fi

# Keep --deadline below info.json's timeout.
raytile submit --server "$RAYTILE_SERVER" --assignment "$RAYTILE_ASSIGNMENT" \
  --student "$STUDENT" --report prairielearn --deadline 180 \
  -o "$ROOT/results/results.json" "$WORK/out"
