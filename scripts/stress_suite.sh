#!/usr/bin/env bash
# The whole test suite on a machine whose CPU is saturated by another process, several times in a row.
#
# Each round starts `stress-ng --cpu N` (N = the number of CPUs, by default; one busy-looping worker
# per CPU at normal priority, so the tests get at most about half of the machine), runs
# `python -m pytest -q` (the project's own options: two workers, --dist loadgroup), and stops
# stress-ng again — also when pytest fails or the script is interrupted (Ctrl-C, SIGTERM).  It
# prints each round's result and time and, at the end, one line per round; it exits 0 only if
# every round passed.  Not part of .ci/run (three rounds take several times the suite's time).
#
#   scripts/stress_suite.sh                      # 3 rounds, stress-ng --cpu $(nproc)
#   ROUNDS=1 STRESS_CPUS=4 scripts/stress_suite.sh -x tests/service   # pytest arguments after the options
#   PYTHON=/path/to/venv/bin/python scripts/stress_suite.sh
#
# Needs stress-ng (Debian/Ubuntu: apt-get install stress-ng; as root where it is missing the script
# installs it with apt-get).  Pytest's temporary folders go to a temporary directory removed on exit.
set -uo pipefail
cd "$(dirname "$0")/.."

ROUNDS="${ROUNDS:-3}"
STRESS_CPUS="${STRESS_CPUS:-$(nproc)}"
PYTHON="${PYTHON:-python3}"

if ! command -v stress-ng >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "stress-ng missing: installing it with apt-get" >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends stress-ng >/dev/null \
            || { apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive \
                 apt-get install -y -qq --no-install-recommends stress-ng >/dev/null; } \
            || { echo "could not install stress-ng" >&2; exit 2; }
    else
        echo "stress-ng is not installed (Debian/Ubuntu: sudo apt-get install stress-ng)" >&2
        exit 2
    fi
fi

tmp="$(mktemp -d)"
stress_pid=""

stop_stress() {
    if [ -n "$stress_pid" ] && kill -0 "$stress_pid" 2>/dev/null; then
        # stress-ng's parent stops its workers on SIGTERM; its process group makes sure none is left
        kill -TERM -- "-$stress_pid" 2>/dev/null || kill -TERM "$stress_pid" 2>/dev/null
        for _ in $(seq 50); do kill -0 "$stress_pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL -- "-$stress_pid" 2>/dev/null || true
        wait "$stress_pid" 2>/dev/null
    fi
    stress_pid=""
}

cleanup() {
    stop_stress
    rm -rf "$tmp"
}
trap cleanup EXIT
trap 'echo "interrupted" >&2; exit 130' INT TERM

results=()
failed=0
for round in $(seq "$ROUNDS"); do
    # a process group of its own (setsid), so that stopping it stops every stress-ng worker
    setsid stress-ng --cpu "$STRESS_CPUS" --timeout 0 --quiet &
    stress_pid=$!
    sleep 1
    if ! kill -0 "$stress_pid" 2>/dev/null; then
        echo "stress-ng did not start" >&2
        exit 2
    fi
    echo "=== round $round/$ROUNDS: stress-ng --cpu $STRESS_CPUS (pid $stress_pid) + python -m pytest -q $*"
    t0=$(date +%s)
    "$PYTHON" -m pytest -q --basetemp "$tmp/pytest-$round" -p no:cacheprovider "$@" 2>&1 | tee "$tmp/round-$round.log"
    rc=${PIPESTATUS[0]}
    t1=$(date +%s)
    stop_stress
    summary="$(grep -E '^(=+ )?[0-9]+ (passed|failed)|(passed|failed|error).* in [0-9.]+s' "$tmp/round-$round.log" | tail -1)"
    line="round $round: exit $rc, $((t1 - t0)) s: ${summary:-no summary line}"
    echo "=== $line"
    results+=("$line")
    [ "$rc" = 0 ] || failed=1
    rm -rf "$tmp/pytest-$round"
done

echo
echo "stress-ng --cpu $STRESS_CPUS, $ROUNDS round(s):"
printf '  %s\n' "${results[@]}"
exit "$failed"
