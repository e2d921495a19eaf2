# broker_lib.sh — sourced by the broker's process tests: start and stop
# `biotgrid broker` daemons on ephemeral loopback ports, and poll jobs.
#   start_broker BIN DIR NAME CONFIG   → $DIR/$NAME.ready "URL ENDPOINT PID", $DIR/$NAME.rc at exit
#   stop_broker DIR NAME               SIGTERM, SIGKILL after 10 s (and fail)
#   wait_job URL ID SECONDS            prints the final state (or "timeout")
#   submit_job URL FILE                POSTs the submission FILE to /v1/jobs; prints the job's id
#   same_energy REPORT REFERENCE       whether two report.json files' first runs have the same
#                                      energy (1e-10 relative to the reference's)
#   check STATUS MESSAGE               "ok: MESSAGE", or "FAIL: MESSAGE" and fail=1
#   bcurl ARGS...                      curl with the test's bearer token ($BIOTGRID_TOKEN, which
#                                      start_broker and grid_up_market export): every /v1 path
#                                      needs one
#   grid_up_market BIN CONFIG STATE    `grid up` on ephemeral loopback ports; sets url and
#                                      nagents; waits until every agent's service seller and the
#                                      host's one resource seller are alive on the market, the
#                                      other agents standing by (checks each step)
#   market_sellers URL KIND            alive market sellers: KIND service, resource or idle
#                                      (service sellers with every slot free)
#   broker_test_begin WORK             WORK emptied, fail=0, INT/TERM stop broker b, exit 1
#   broker_agents_test_begin WORK SCRIPTS
#                                      WORK emptied, fail=0; at exit broker b and the agents
#                                      of WORK/agents are stopped; INT/TERM/HUP exit 1
#   broker_config WORK NAME [JSON]     WORK/broker.json: ephemeral loopback ports, WORK/state
#   grid_test_begin BIN WORK           a grid test's start: WORK emptied, state=WORK/grid,
#                                      fail=0, INT/TERM stop the grid and exit 1
#   grid_test_end SCRIPTS              `grid down` (to WORK/down.txt) and no process of the
#                                      grid left (SCRIPTS/no_agents_left.sh), both checked
#   bcurl ARGS...                      the REST API: curl with what every call needs (the
#                                      bearer token $BIOTGRID_TOKEN); callers add -sf
#   now                                seconds since the epoch, with nanoseconds
#   contracts_closed URL FILE          the broker's contract log into FILE once no row is open
#                                      (a job's rows close a little after it ends), 10 s at most;
#                                      status 1 when a row is still open then
check() {
  if [ "$1" -ne 0 ]; then echo "FAIL: $2" >&2; fail=1; else echo "ok: $2"; fi
}

bcurl() {
  curl -H "Authorization: Bearer ${BIOTGRID_TOKEN:-}" "$@"
}

now() { date +%s.%N; }

contracts_closed() {
  _i=0
  while :; do
    bcurl -sf "$1/v1/market/contracts.csv" >"$2"
    awk -F, 'NR > 1 && $8 - $7 > 1e8 { open++ } END { exit open > 0 }' "$2" && return 0
    [ $_i -lt 100 ] || return 1
    sleep 0.1
    _i=$((_i + 1))
  done
}

# An admin token for the broker whose state folder is $2, exported as
# BIOTGRID_TOKEN for bcurl and the biotgrid client commands.
export_token() {
  BIOTGRID_TOKEN=$("$1" token create tests --admin --state-dir "$2" 2>/dev/null)
  export BIOTGRID_TOKEN
  [ -n "$BIOTGRID_TOKEN" ]
}

# The admin token `grid up` wrote to the state folder $1, exported as
# BIOTGRID_TOKEN; checked to exist and be readable by its owner only.
grid_token() {
  BIOTGRID_TOKEN=$(head -1 "$1/token" 2>/dev/null)
  export BIOTGRID_TOKEN
  [ -n "$BIOTGRID_TOKEN" ] && [ "$(stat -c %a "$1/token")" = 600 ]
  check $? "grid up wrote an admin token only its owner may read"
}

start_broker() {
  _bin=$1 _dir=$2 _name=$3 _config=$4
  rm -f "$_dir/$_name.ready" "$_dir/$_name.rc"
  ( "$_bin" broker --config "$_config" --ready-file "$_dir/$_name.ready" \
      >"$_dir/$_name.log" 2>&1 </dev/null
    echo $? >"$_dir/$_name.rc" ) >/dev/null 2>&1 </dev/null &
  _i=0
  while [ ! -s "$_dir/$_name.ready" ] && [ ! -s "$_dir/$_name.rc" ] && [ $_i -lt 100 ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  if [ ! -s "$_dir/$_name.ready" ]; then
    echo "start_broker: $_name did not become ready" >&2
    cat "$_dir/$_name.log" >&2
    return 1
  fi
  export_token "$_bin" "$(jq -r '.state_dir // "out/broker"' "$_config")" ||
    { echo "start_broker: no token for $_name" >&2; return 1; }
}

stop_broker() {
  _dir=$1 _name=$2
  [ -s "$_dir/$_name.ready" ] || return 0
  _pid=$(cut -d' ' -f3 "$_dir/$_name.ready")
  [ -s "$_dir/$_name.rc" ] || kill -TERM "$_pid" 2>/dev/null
  _i=0
  while [ ! -s "$_dir/$_name.rc" ] && [ $_i -lt 100 ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  if [ ! -s "$_dir/$_name.rc" ]; then
    echo "stop_broker: $_name (pid $_pid) ignored SIGTERM for 10 s: SIGKILL" >&2
    kill -KILL "$_pid" 2>/dev/null
    return 1
  fi
  _rc=$(cat "$_dir/$_name.rc")
  [ "$_rc" = 0 ] || { echo "stop_broker: $_name exited with $_rc" >&2; return 1; }
}

submit_job() {
  bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$2" "$1/v1/jobs" | jq -r .id
}

same_energy() {
  jq -n --slurpfile a "$1" --slurpfile b "$2" \
    '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' \
    | grep -q true
}

wait_job() {
  _url=$1 _id=$2 _limit=$3
  _i=0 _bad=0
  while [ $_i -lt $((_limit * 10)) ]; do
    if _state=$(bcurl -sf --max-time 10 "$_url/v1/jobs/$_id" | jq -er .state); then
      _bad=0
    else
      _bad=$((_bad + 1))
      [ $_bad -lt 3 ] || { echo "unreachable"; return 0; }
    fi
    case $_state in
      succeeded|failed|cancelled) echo "$_state"; return 0 ;;
    esac
    sleep 0.1
    _i=$((_i + 1))
  done
  echo timeout
}

# agents_matching URL FILTER MIN TRIES: polls the broker's agent list every
# 0.1 s, at most TRIES times, until at least MIN agents match the jq FILTER
# (e.g. '.name == "cut-1" and .alive'); prints how many matched last.
agents_matching() {
  _i=0 _n=0
  while [ $_i -lt "$4" ]; do
    _n=$(bcurl -sf "$1/v1/agents" | jq "[.agents[] | select($2)] | length")
    [ "${_n:-0}" -ge "$3" ] && break
    sleep 0.1
    _i=$((_i + 1))
  done
  echo "${_n:-0}"
}

market_sellers() {
  case $2 in
  service) _sel='(.services | length) > 0' ;;
  resource) _sel='(.services | length) == 0 and .slots == 0' ;;
  idle) _sel='(.services | length) > 0 and .free_slots == .slots' ;;
  esac
  bcurl -sf "$1/v1/agents" | jq "[.agents[] | select(.source == \"market\" and .alive and $_sel)] | length"
}

grid_up_market() {
  _bin=$1 _config=$2 _state=$3
  "$_bin" grid up "$_config" --state "$_state" --broker-port 0 \
    --broker-endpoint 'tcp://127.0.0.1:*' >"$_state.up.txt" 2>&1
  check $? "grid up"
  url=$(jq -r '.broker.url // empty' "$_state/grid.json" 2>/dev/null)
  [ -n "$url" ]; check $? "the state file records the broker ($url)"
  grid_token "$_state"
  nagents=$(jq '.agents | length' "$_config")
  # Each agent daemon is a service seller in the directory; the host's
  # cores and memory have one resource seller (no services, no slots), the
  # first daemon to register, and the others say they stand by.
  _i=0 _live=0 _res=0 _by=0
  while [ $_i -lt 200 ]; do
    _live=$(market_sellers "$url" service) _res=$(market_sellers "$url" resource)
    _by=$(cat "$_state"/*.log 2>/dev/null | grep -c "resource role stands by")
    [ "${_live:-0}" -ge "$nagents" ] && [ "${_res:-0}" -ge 1 ] &&
      [ "$_by" -ge $((nagents - 1)) ] && break
    sleep 0.1
    _i=$((_i + 1))
  done
  [ "${_live:-0}" -eq "$nagents" ] && [ "${_res:-0}" -eq 1 ] && [ "$_by" -eq $((nagents - 1)) ]
  check $? "all $nagents agents registered on the market, one selling the host's resources (got $_live, $_res; $_by stand by)"
}

# broker_test_begin WORK: WORK emptied, fail=0, INT/TERM stop the broker
# named b (start_broker WORK b) and exit 1.
broker_test_begin() {
  _bt_work=$1
  rm -rf "$_bt_work"
  mkdir -p "$_bt_work"
  fail=0
  trap 'stop_broker "$_bt_work" b; exit 1' INT TERM
}

# broker_agents_test_begin WORK SCRIPTS: WORK emptied, fail=0; whenever the
# test exits, the broker named b and the agents SCRIPTS/start_agents.sh
# started in WORK/agents are stopped, unchecked (a test that ends normally
# stops them itself, checked, after `trap - EXIT`); INT, TERM and HUP exit 1.
broker_agents_test_begin() {
  _bat_work=$1 _bat_scripts=$2
  rm -rf "$_bat_work"
  mkdir -p "$_bat_work"
  fail=0
  trap 'stop_broker "$_bat_work" b >/dev/null 2>&1
        sh "$_bat_scripts/stop_agents.sh" "$_bat_work/agents" >/dev/null 2>&1' EXIT
  trap 'exit 1' INT TERM HUP
}

# broker_config WORK NAME [JSON]: WORK/broker.json for a broker named NAME
# on ephemeral loopback ports with its state in WORK/state, JSON's keys
# (an object) added.
broker_config() {
  _bc_extra=${3:-}
  [ -n "$_bc_extra" ] || _bc_extra='{}'
  jq -n --arg n "$2" --arg d "$1/state" --argjson x "$_bc_extra" \
    '{name: $n, port: 0, endpoint: "tcp://127.0.0.1:*", state_dir: $d} + $x' >"$1/broker.json"
}

grid_test_begin() {
  _gt_bin=$1 _gt_work=$2
  rm -rf "$_gt_work"
  mkdir -p "$_gt_work"
  state="$_gt_work/grid"
  fail=0
  trap '"$_gt_bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM
}

grid_test_end() {
  "$_gt_bin" grid down --state "$state" >"$_gt_work/down.txt" 2>&1
  check $? "grid down"
  sh "$1/no_agents_left.sh" "$state"; check $? "no process of the grid is left"
}
