# Sourced by the package tests: one line per check ("ok" or "FAIL"), counted for the closing
# "NAME: N passed, M failed" that scripts/test tallies. Needs $WORK, a scratch directory.
PASSED=0
FAILED=0
say() { printf -- '--- %s\n' "$*"; }
ok() { printf 'ok    %s\n' "$*"; PASSED=$((PASSED + 1)); }
fail() { printf 'FAIL  %s\n' "$*"; FAILED=$((FAILED + 1)); }
check() {   # check "what" command...: one line, and the command's output when it fails
    local what=$1; shift
    if "$@" >"$WORK/out" 2>&1; then ok "$what"; else fail "$what"; sed 's/^/      /' "$WORK/out"; fi
}
show() {    # show "what" command...: the same, with the command's output either way
    local what=$1; shift
    if "$@" >"$WORK/out" 2>&1; then ok "$what"; else fail "$what"; fi
    sed 's/^/      /' "$WORK/out"
}
tally() {   # tally NAME: the closing line; the exit status says whether all passed
    echo "$1: $PASSED passed, $FAILED failed"
    [ "$FAILED" -eq 0 ]
}
