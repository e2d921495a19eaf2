#!/bin/sh
# netns.sh up|down|probe|sweep STATE_DIR [FIXTURE_DIR]
# The multi-host hosts: Linux network namespaces joined by a bridge, all
# on this machine. Each test makes its own (up, from mh_begin) and removes
# them on any exit (down, from its EXIT trap), so no namespace outlives
# the test that made it; the CTest fixture only probes and sweeps.
#
#   up    makes, for one test, namespaces RUN-sw (the switch: a bridge
#         and one veth per host, nothing else), RUN-b (the broker's host),
#         RUN-h1 and RUN-h2 (two agents' hosts) and RUN-x (a stranger's
#         host), each host on the bridge through its own veth pair with an
#         address 10.77.N.* /24, N chosen so no interface of this machine
#         is in that subnet. RUN is unique per run (the PID and random
#         bytes) and is appended to FIXTURE_DIR/runs when given. The switch
#         has no link to this machine's namespace and no host has a route
#         beyond 10.77.N.0/24, so no packet leaves the bridge. It checks
#         every host reaches the broker's host, writes STATE_DIR/env (the
#         names and addresses, for the tests) and exits 0; where namespaces
#         cannot be made (not root, no `ip`, no veth or bridge support) it
#         says why in STATE_DIR/skip, undoes what it made and exits 77
#         (CTest SKIP_RETURN_CODE: skipped, never passed).
#   down  stops every process still in the run's namespaces (SIGTERM,
#         SIGKILL after 5 s; one found there outlived its test: a failure),
#         deletes the namespaces (the bridge and veths go with them),
#         checks nothing of the run is left and exits 0, or 1 if something
#         was; 77 when up was skipped.
#   probe up then down at once (multihost.net_up, the FIXTURES_SETUP):
#         exits 0 when namespaces can be made here, else 77 with the reason
#         in STATE_DIR/skip, which the tests then report as their skip.
#   sweep (multihost.net_down, the FIXTURES_CLEANUP, run after a failure
#         or a timeout too): every run listed in STATE_DIR/runs whose
#         namespaces are still there is removed, and that is a failure.
#
# Tests run a command on a host with:
#   . STATE_DIR/env && host_exec "$NS_B" biotgrid ...
# which runs it under `setpriv --pdeathsig KILL`, so it dies with the
# test's shell whatever kills that (a CTest timeout included).
set -u
SKIP=77
mode=${1:-} state=${2:-} fixture=${3:-}
usage="usage: netns.sh up|down|probe|sweep STATE_DIR [FIXTURE_DIR]"
[ -n "$mode" ] && [ -n "$state" ] || { echo "$usage" >&2; exit 2; }

say() { echo "netns: $*"; }

skip() {
  say "SKIPPED: $*"
  mkdir -p "$state"
  echo "$*" >"$state/skip"
  exit $SKIP
}

# Every process in namespace $1 stopped: SIGTERM, then SIGKILL after 5 s.
stop_all_in() {
  _pids=$(ip netns pids "$1" 2>/dev/null)
  [ -n "$_pids" ] || return 0
  say "FAIL: $(echo $_pids | wc -w) process(es) outlived their test in $1: $(echo $_pids)"
  leftover=1
  kill -TERM $_pids 2>/dev/null
  _i=0
  while [ -n "$(ip netns pids "$1" 2>/dev/null)" ] && [ $_i -lt 50 ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  _pids=$(ip netns pids "$1" 2>/dev/null)
  [ -z "$_pids" ] || { say "SIGKILL to $(echo $_pids)"; kill -KILL $_pids 2>/dev/null; }
  _i=0
  while [ -n "$(ip netns pids "$1" 2>/dev/null)" ] && [ $_i -lt 50 ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
}

# Removes every namespace whose name starts with $1- (stopping what runs there).
remove_run() {
  for _ns in $(ip netns list 2>/dev/null | awk '{print $1}' | grep "^$1-"); do
    stop_all_in "$_ns"
    ip netns delete "$_ns" 2>/dev/null || say "cannot delete namespace $_ns"
  done
}

if [ "$mode" = probe ]; then
  sh "$0" up "$state/probe" || {
    rc=$?
    [ -e "$state/probe/skip" ] && cp "$state/probe/skip" "$state/skip"
    exit $rc
  }
  sh "$0" down "$state/probe"
  exit $?
fi

if [ "$mode" = sweep ]; then
  [ -e "$state/skip" ] && { say "nothing to sweep: skipped ($(cat "$state/skip"))"; exit $SKIP; }
  leftover=0
  for r in $(cat "$state/runs" 2>/dev/null); do
    if ip netns list 2>/dev/null | awk '{print $1}' | grep -q "^$r-"; then
      say "FAIL: the namespaces of run $r outlived their test"
      leftover=1
      remove_run "$r"
    fi
  done
  left=$(ip netns list 2>/dev/null | awk '{print $1}' | grep -E "^($(cat "$state/runs" 2>/dev/null | tr '\n' '|')x)-" )
  [ -z "$left" ] || { say "FAIL: namespaces left: $left"; exit 1; }
  say "no namespace of this group's $(wc -l <"$state/runs" 2>/dev/null || echo 0) run(s) is left"
  exit $leftover
fi

if [ "$mode" = down ]; then
  if [ -e "$state/skip" ]; then
    say "nothing to remove: the fixture was skipped ($(cat "$state/skip"))"
    exit $SKIP
  fi
  [ -s "$state/env" ] || { say "no $state/env: was the fixture made?"; exit 1; }
  . "$state/env"
  leftover=0
  remove_run "$RUN"
  left=$(ip netns list 2>/dev/null | awk '{print $1}' | grep "^$RUN-")
  if [ -n "$left" ]; then
    say "FAIL: namespaces left: $left"
    exit 1
  fi
  say "removed the namespaces of run $RUN (and the bridge and veths in them)"
  exit $leftover
fi

[ "$mode" = up ] || { echo "$usage" >&2; exit 2; }
rm -rf "$state"
mkdir -p "$state"
[ "$(id -u)" = 0 ] || skip "network namespaces need root (uid $(id -u))"
command -v ip >/dev/null 2>&1 || skip "no 'ip' command (iproute2)"

RUN="bgmh$$$(od -An -N3 -tx1 /dev/urandom | tr -d ' \n')"
trap 'remove_run "$RUN"; exit 1' INT TERM HUP
[ -z "$fixture" ] || echo "$RUN" >>"$fixture/runs"
ip netns add "$RUN-sw" 2>"$state/why" ||
  skip "cannot make a network namespace: $(cat "$state/why")"

# The subnet: 10.77.N.0/24 with N not used by any interface of this machine.
used=$(ip -4 -o addr show 2>/dev/null | sed -n 's/.* inet 10\.77\.\([0-9]*\)\..*/\1/p' | sort -u)
N=""
start=$(( $(od -An -N1 -tu1 /dev/urandom | tr -d ' ') % 250 + 1 ))
for k in $(seq 0 249); do
  cand=$(( (start + k - 1) % 250 + 1 ))
  echo "$used" | grep -qx "$cand" || { N=$cand; break; }
done
[ -n "$N" ] || { remove_run "$RUN"; skip "every 10.77.N.0/24 is in use on this machine"; }
NET=10.77.$N

fail_setup() {
  _why="$1: $(cat "$state/why" 2>/dev/null)"
  remove_run "$RUN"
  skip "$_why"
}

ip -n "$RUN-sw" link set lo up 2>"$state/why" || fail_setup "switch loopback"
ip -n "$RUN-sw" link add br0 type bridge 2>"$state/why" || fail_setup "no bridge support"
ip -n "$RUN-sw" link set br0 up 2>"$state/why" || fail_setup "bridge up"
# host: name, last byte of its address
for h in b:1 h1:11 h2:12 x:13; do
  name=${h%%:*} byte=${h##*:}
  ns="$RUN-$name"
  ip netns add "$ns" 2>"$state/why" || fail_setup "namespace $ns"
  ip -n "$ns" link set lo up 2>"$state/why" || fail_setup "$ns loopback"
  # The pair is made inside the switch, its host end moved into the host:
  # no interface ever appears in this machine's own namespace.
  ip -n "$RUN-sw" link add "v$name" type veth peer name eth0 netns "$ns" 2>"$state/why" ||
    fail_setup "no veth support"
  ip -n "$RUN-sw" link set "v$name" master br0 2>"$state/why" || fail_setup "bridge port v$name"
  ip -n "$RUN-sw" link set "v$name" up 2>"$state/why" || fail_setup "v$name up"
  ip -n "$ns" addr add "$NET.$byte/24" dev eth0 2>"$state/why" || fail_setup "$ns address"
  ip -n "$ns" link set eth0 up 2>"$state/why" || fail_setup "$ns eth0 up"
done

cat >"$state/env" <<EOF
# The multi-host fixture of run $RUN (tests/multihost/netns.sh).
RUN=$RUN
NET=$NET
NS_SW=$RUN-sw
NS_B=$RUN-b
NS_H1=$RUN-h1
NS_H2=$RUN-h2
NS_X=$RUN-x
IP_B=$NET.1
IP_H1=$NET.11
IP_H2=$NET.12
IP_X=$NET.13
host_exec() { _ns=\$1; shift; ip netns exec "\$_ns" setpriv --pdeathsig KILL -- "\$@"; }
EOF

# Every host has its route to the broker's host on the bridge (the tests
# themselves then connect across it).
. "$state/env"
for ns in "$NS_H1" "$NS_H2" "$NS_X"; do
  ip -n "$ns" route get "$IP_B" 2>"$state/why" | grep -q "dev eth0" ||
    fail_setup "no route from $ns to $IP_B"
done
# No host routes beyond the bridge's subnet.
for ns in "$NS_B" "$NS_H1" "$NS_H2" "$NS_X"; do
  if ip -n "$ns" route show default 2>/dev/null | grep -q .; then
    remove_run "$RUN"
    say "FAIL: $ns has a default route"
    exit 1
  fi
done
say "run $RUN: switch $NS_SW (bridge br0), broker host $NS_B $IP_B, agent hosts $NS_H1 $IP_H1 and $NS_H2 $IP_H2, stranger $NS_X $IP_X, subnet $NET.0/24"
exit 0
