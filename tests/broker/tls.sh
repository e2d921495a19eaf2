#!/bin/sh
# tls.sh BIOTGRID WORKDIR
# REST over TLS: a broker bound beyond loopback without a certificate is
# refused before it listens (exit 2 naming --tls-cert), --insecure lets it
# go on; a certificate without its key, or a key that is not the
# certificate's, is exit 2 saying so; with a certificate the broker serves
# https only, and a client trusts it through --cacert or $BIOTGRID_CACERT,
# refuses it otherwise (exit 1 naming --cacert), as it refuses a
# certificate signed by another CA.
set -u
bin=$1 work=$2
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_test_begin "$work"

# Two self-signed certificates for 127.0.0.1 (P-256, a day): A serves,
# B is another party's.
for n in a b; do
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 1 \
    -subj "/CN=biotgrid test $n" -addext "subjectAltName=IP:127.0.0.1" \
    -keyout "$work/$n.key" -out "$work/$n.pem" >/dev/null 2>&1 ||
    { echo "FAIL: openssl cannot make a test certificate" >&2; exit 1; }
done
broker_config "$work" tls

# Refusals: each exits 2 before anything listens, with a message naming the fix.
refused() { # WHAT PATTERN ARGS...
  _what=$1 _pat=$2
  shift 2
  timeout 20 "$bin" broker --config "$work/broker.json" "$@" >"$work/out.txt" 2>&1
  _rc=$?
  [ $_rc -eq 2 ] && grep -q -- "$_pat" "$work/out.txt"
  check $? "$_what: exit 2 saying '$_pat' (exit $_rc: $(head -c 300 "$work/out.txt"))"
}
refused "plain HTTP on 0.0.0.0" "beyond loopback.*--tls-cert FILE --tls-key FILE.*--insecure" \
  --address 0.0.0.0
refused "plain HTTP on 10.255.255.1" "10.255.255.1 is beyond loopback" --address 10.255.255.1
refused "a certificate without its key" "go together" --tls-cert "$work/a.pem"
refused "a key that is not the certificate's" "do not load as a PEM pair" \
  --tls-cert "$work/a.pem" --tls-key "$work/b.key"
refused "a certificate file that is not PEM" "not a PEM file" \
  --tls-cert "$work/broker.json" --tls-key "$work/a.key"
refused "a certificate file that does not exist" "tls-cert.*nothing.pem" \
  --tls-cert "$work/nothing.pem" --tls-key "$work/a.key"
# --insecure passes the check: the broker goes on to bind the address
# (which no interface here has, so nothing listens beyond loopback).
timeout 20 "$bin" broker --config "$work/broker.json" --address 10.255.255.1 --insecure \
  >"$work/out.txt" 2>&1
rc=$?
[ $rc -eq 1 ] && grep -q "cannot listen on 10.255.255.1" "$work/out.txt"
check $? "--insecure lets a plain broker try 10.255.255.1 (exit $rc: $(head -c 200 "$work/out.txt"))"

# A TLS broker, its certificate from the config file.
jq --arg c "$work/a.pem" --arg k "$work/a.key" '. + {tls_cert: $c, tls_key: $k}' \
  "$work/broker.json" >"$work/tls.json"
start_broker "$bin" "$work" b "$work/tls.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
case $url in https://127.0.0.1:*) r=0 ;; *) r=1 ;; esac
check $r "the ready file names an https URL ($url)"
code=$(curl -s --cacert "$work/a.pem" -o /dev/null -w '%{http_code}' "$url/healthz")
[ "$code" = 200 ]; check $? "/healthz over TLS with the broker's certificate trusted (got $code)"
plain=$(printf '%s' "$url" | sed 's/^https/http/')
curl -s --max-time 5 -o /dev/null "$plain/healthz"
[ $? -ne 0 ]; check $? "plain HTTP to the TLS port gets no answer"
curl -s --max-time 5 -o /dev/null "$url/healthz"
[ $? -eq 60 ]; check $? "curl without the certificate refuses it (exit 60: peer verification)"
curl -s --tls-max 1.1 --cacert "$work/a.pem" --max-time 5 -o /dev/null "$url/healthz"
[ $? -ne 0 ]; check $? "TLS 1.1 and older are refused"

scene=$here/../../configs/scenes/bar-twist.json
"$bin" submit "$scene" --broker "$url" --cacert "$work/a.pem" >"$work/submit.txt" 2>&1
rc=$?
id=$(grep -o 'j[0-9a-f]\{16\}' "$work/submit.txt" | head -1)
[ $rc -eq 0 ] && [ -n "$id" ]; check $? "submit over TLS with --cacert (exit $rc, job $id)"
BIOTGRID_CACERT="$work/a.pem" "$bin" jobs --broker "$url" --json >"$work/jobs.json" 2>"$work/jobs.err"
jq -e --arg id "$id" '[.jobs[].id] | index($id) != null' "$work/jobs.json" >/dev/null
check $? "jobs over TLS with \$BIOTGRID_CACERT lists it"
"$bin" jobs --broker "$url" >"$work/untrusted.txt" 2>&1
rc=$?
[ $rc -eq 1 ] && grep -q "certificate is not trusted.*--cacert FILE" "$work/untrusted.txt"
check $? "without --cacert the client refuses the certificate, naming --cacert (exit $rc: $(head -c 300 "$work/untrusted.txt"))"
"$bin" jobs --broker "$url" --cacert "$work/b.pem" >"$work/other.txt" 2>&1
rc=$?
[ $rc -eq 1 ] && grep -q "not trusted" "$work/other.txt"
check $? "a certificate signed by another CA is refused (exit $rc)"
"$bin" jobs --broker "$plain" >"$work/plain.txt" 2>&1
rc=$?
[ $rc -eq 1 ] && grep -q "does it serve https" "$work/plain.txt"
check $? "an http:// URL to the TLS broker says to name it https:// (exit $rc: $(head -c 300 "$work/plain.txt"))"
stop_broker "$work" b; check $? "the TLS broker stops on SIGTERM with status 0"
exit $fail
