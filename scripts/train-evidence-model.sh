#!/bin/sh
# Re-run the 67 simulated tuning nights of the shipped evidence model with this release
# and train it again (docs/detection.md, "The evidence model"). Needs the `train` extra
# (scikit-learn). About 75 minutes of simulation and tracking on 2 cores, then ~20 of
# training. Nights run under the rules: the features do not depend on the decision.
#
#   scripts/train-evidence-model.sh OUT_DIR [firefly3d]
#
# RULES_EXTRA adds ProcessParams of the nights' runs, as JSON members, e.g. to train on
# the candidates of tracking without the crowded-flash seeds (docs/detection.md,
# "Crowded flashes"):
#
#   RULES_EXTRA='"tracking": {"deblend": false}' scripts/train-evidence-model.sh OUT_DIR
#
# writes OUT_DIR/g*.json (eval-detection), OUT_DIR/<night>/ (runs) and
# OUT_DIR/evidence_trees.json (the model; its cut is where the two passes accept out of
# fold as many false candidates as the first pass alone at 0.625, the one-pass model's
# operating point).
set -eu
out=${1:?usage: $0 OUT_DIR [firefly3d]}
cli=${2:-firefly3d}
mkdir -p "$out"
echo "{\"acceptance\": {\"evidence_model\": null}${RULES_EXTRA:+, $RULES_EXTRA}}" > "$out/rules.json"
echo '{"fps": 60}' > "$out/fps60.json"
nights() { # name, then eval-detection arguments
    name=$1
    shift
    "$cli" eval-detection --quiet --params "$out/rules.json" --out "$out" \
        --json "$out/g-$name.json" "$@"
}
hard="--scenario hard-clean --scenario hard-wind --scenario hard-all"
nights 640-hard --width 640 $hard --scenario hard-swarm --scenario hard-species \
    --scenario hard-noisy --seeds 12 13 14 15
nights 640-easy --width 640 --scenario clean --scenario field --scenario foliage \
    --scenario headlights --scenario twilight --scenario lights --seeds 12 13
nights 640-60fps --width 640 --seconds 15 --sim-params "$out/fps60.json" $hard \
    --scenario hard-species --scenario hard-noisy --seeds 14 15
nights 1280 --width 1280 $hard --scenario hard-swarm --scenario hard-species \
    --scenario hard-noisy --seeds 12 13
nights 3840 --width 3840 --seconds 12 $hard --scenario hard-species --seeds 12 13
nights 3840-noisy --width 3840 --seconds 12 --scenario hard-noisy --seeds 13
"$cli" train-acceptance --runs "$out"/g-*.json --false-as-first-pass-at 0.625 \
    --out "$out/evidence_trees.json"
