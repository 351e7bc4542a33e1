# Sourced by the record folders' compare.sh scripts: `se3push compare` over folder pairs given
# one "A B" a line on stdin.

each() {  # each pair's success and median-steps lines, or the lines sed script $1 picks
    local lines=${1:-"2p;/^median steps/p"} a b
    while read -r a b; do
        echo "== $a vs $b"
        se3push compare "$a" "$b" | sed -n "$lines"
    done
}

pool() {  # the pooled line over all the pairs
    local args=() a b
    while read -r a b; do
        if ((${#args[@]})); then args+=(--pair "$a" "$b"); else args+=("$a" "$b"); fi
    done
    se3push compare "${args[@]}" | tail -1
}

set2() {  # trial set 2's three scenarios, A's folder prefix against B's
    for s in single_box multi_object heldout_objects; do echo "$1$s $2$s"; done
}

both_plans() {  # the seven sets of 50 both models ran with both plans, long against the default
    local m=$1 H=docs/results/trials/headline P=docs/results/trials/pre_push_seed5
    set2 "$H/${m}_h12_" "$H/${m}_surface_"
    echo "$P/${m}_long_heldout_objects $P/${m}_surface_heldout_objects"
    echo "docs/results/trials/near_horizon/s5_${m}_long_multi_object $P/${m}_surface_multi_object"
    echo "docs/results/trials/stall/s8_${m}_long_heldout_objects docs/results/trials/stall/s8_${m}_heldout_objects"
    echo "docs/results/trials/pinned/s9_${m}_long_heldout_objects docs/results/trials/pinned/s9_${m}_heldout_objects"
}
