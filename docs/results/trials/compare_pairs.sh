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
