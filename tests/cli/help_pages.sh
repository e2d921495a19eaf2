#!/bin/sh
# help_pages.sh BIOTGRID MANPAGE: `biotgrid help C` prints exactly what
# `biotgrid C --help` prints for every command, each exits 0, and the
# generated manual page carries each command's usage line.
set -u
bin=$1 man=$2
status=0
commands=$("$bin" help | sed -n 's/^  \([a-z][a-z-]*\) .*/\1/p' | grep -v '^help$')
[ -n "$commands" ] || { echo "help_pages.sh: no commands listed by '$bin help'" >&2; exit 1; }
[ -s "$man" ] || { echo "help_pages.sh: $man missing or empty" >&2; exit 1; }
for c in $commands; do
    a=$("$bin" help "$c") || { echo "help $c: exit $?" >&2; status=1; }
    b=$("$bin" "$c" --help) || { echo "$c --help: exit $?" >&2; status=1; }
    if [ "$a" != "$b" ]; then
        echo "help_pages.sh: 'help $c' and '$c --help' differ" >&2
        status=1
    fi
    first=$(printf '%s\n' "$b" | head -n 1)
    case $first in
        usage:*) ;;
        *) echo "help_pages.sh: '$c --help' does not start with a usage line" >&2; status=1 ;;
    esac
    if ! grep -qF -- "$first" "$man"; then
        echo "help_pages.sh: the manual page lacks '$first'" >&2
        status=1
    fi
    echo "$c: help page ok"
done
exit $status
