# mh_lib.sh — sourced by the multi-host tests (after broker_lib.sh): the
# test's own hosts (netns.sh), and daemons started on them.
#   mh_begin FIXTURE WORK      WORK emptied, then this test's own hosts made
#                              (netns.sh up WORK/net, the run listed in
#                              FIXTURE/runs) and their env loaded, or exit 77
#                              (skipped) saying why they cannot be made; on
#                              any exit (a failure, a signal) the daemons
#                              still running are stopped and the namespaces
#                              removed (netns.sh down: one that still held a
#                              process, or could not be removed, fails the test)
#   mh_keys DIR NAME...        a key pair DIR/NAME.{key,pub} per name
#   mh_broker NS NAME STATE ARGS...
#                              `biotgrid broker --state-dir STATE` on host NS
#                              (REST on that host's loopback), logs
#                              WORK/NAME.log; waits for WORK/NAME.ready ("URL
#                              ENDPOINT PID"); sets url, and BIOTGRID_TOKEN (an
#                              admin token)
#   mh_agent NS NAME ARGS...   `biotgrid agent` on host NS, WORK/NAME.log
#   mh_stop_all                SIGTERM to every daemon started, each must exit
#                              within 10 s (else SIGKILL and failure); their
#                              exit statuses in WORK/NAME.rc
#   bcurl ARGS...              curl on the broker's host with the token
#   wait_for FILE SECONDS TEXT whether FILE holds the fixed TEXT within SECONDS
# Every daemon runs under `setpriv --pdeathsig KILL`: it dies with
# the test's shell even when that is SIGKILLed, and the fixture's sweep
# (multihost.net_down) removes any namespace a killed test left.

mh_begin() {
  _fixture=$1 work=$2
  if [ -e "$_fixture/skip" ]; then
    echo "SKIPPED: network namespaces cannot be made here: $(cat "$_fixture/skip")"
    exit 77
  fi
  rm -rf "$work"
  mkdir -p "$work" "$_fixture"
  fail=0
  mh_daemons=""
  trap 'mh_end' EXIT
  trap 'exit 1' INT TERM HUP
  sh "$here/netns.sh" up "$work/net" "$_fixture"
  _rc=$?
  if [ $_rc -eq 77 ]; then
    trap - EXIT
    echo "SKIPPED: $(cat "$work/net/skip" 2>/dev/null)"
    exit 77
  fi
  [ $_rc -eq 0 ] || { echo "FAIL: the test's namespaces were not made" >&2; exit 1; }
  . "$work/net/env"
}

# The EXIT trap: what runs is stopped, the namespaces removed; the test's
# status is kept, or made a failure when the removal found a leftover.
mh_end() {
  _rc=$?
  trap - EXIT
  [ -z "$mh_daemons" ] || { echo "stopping the daemons still running (the test ended early)"; mh_stop_all; }
  sh "$here/netns.sh" down "$work/net" || _rc=1
  [ -z "$(ip netns list 2>/dev/null | awk '{print $1}' | grep "^$RUN-")" ] ||
    { echo "FAIL: namespaces of run $RUN left" >&2; _rc=1; }
  exit $_rc
}

mh_keys() {
  _dir=$1
  shift
  mkdir -p "$_dir"
  for _n in "$@"; do
    "$bin" keygen "$_dir/$_n" >/dev/null || { echo "FAIL: keygen $_n" >&2; fail=1; }
  done
}

# A daemon on host $1: `biotgrid ARGS` in the background as a simple
# command, so $! is the daemon itself (ip netns exec and setpriv exec, they
# do not fork) and the test's shell its parent (--pdeathsig fires with it).
mh_broker() {
  _ns=$1 _name=$2 _state_dir=$3
  shift 3
  rm -f "$work/$_name.ready"
  ip netns exec "$_ns" setpriv --pdeathsig KILL -- "$bin" broker --state-dir "$_state_dir" \
    --ready-file "$work/$_name.ready" "$@" >"$work/$_name.log" 2>&1 </dev/null &
  _pid=$!
  mh_daemons="$mh_daemons $_name:$_pid"
  _i=0
  while [ ! -s "$work/$_name.ready" ] && kill -0 $_pid 2>/dev/null && [ $_i -lt 100 ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  if [ ! -s "$work/$_name.ready" ]; then
    echo "mh_broker: $_name did not become ready" >&2
    cat "$work/$_name.log" >&2
    return 1
  fi
  url=$(cut -d' ' -f1 "$work/$_name.ready")
  BIOTGRID_TOKEN=$("$bin" token create tests --admin --state-dir "$_state_dir" 2>/dev/null)
  export BIOTGRID_TOKEN
  [ -n "$BIOTGRID_TOKEN" ]
}

mh_agent() {
  _ns=$1 _name=$2
  shift 2
  ip netns exec "$_ns" setpriv --pdeathsig KILL -- "$bin" agent "$@" >"$work/$_name.log" 2>&1 \
    </dev/null &
  mh_daemons="$mh_daemons $_name:$!"
}

mh_stop_all() {
  _ok=0
  for _d in $mh_daemons; do kill -TERM "${_d#*:}" 2>/dev/null; done
  for _d in $mh_daemons; do
    _name=${_d%%:*} _pid=${_d#*:}
    _i=0
    while kill -0 "$_pid" 2>/dev/null && [ $_i -lt 100 ]; do
      sleep 0.1
      _i=$((_i + 1))
    done
    if kill -0 "$_pid" 2>/dev/null; then
      echo "FAIL: $_name (pid $_pid) still runs 10 s after SIGTERM: SIGKILL" >&2
      kill -KILL "$_pid" 2>/dev/null
      _ok=1
    fi
    wait "$_pid" 2>/dev/null
    echo $? >"$work/$_name.rc"
  done
  mh_daemons=""
  return $_ok
}

bcurl() {
  ip netns exec "$NS_B" curl -H "Authorization: Bearer ${BIOTGRID_TOKEN:-}" "$@"
}

wait_for() {
  _i=0
  while ! grep -qF -- "$3" "$1" 2>/dev/null && [ $_i -lt $(($2 * 10)) ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  grep -qF -- "$3" "$1" 2>/dev/null
}
