#!/bin/sh
# help_pages.sh BIOTGRID MANPAGE: `biotgrid help C` prints exactly what
# `biotgrid C --help` prints for every command, each exits 0, the generated
# manual page carries each command's usage line, and every verb of a
# command with verbs (`grid up --help`, `mesh info --help`) shows its page.
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
# Every verb of a command with verbs takes --help too: exit 0, the command's
# page (its usage line first), nothing on stderr.
errors=$(mktemp) || exit 1
for cv in "grid up" "grid status" "grid down" "mesh info" "mesh convert" "mesh simplify" "token create"; do
    set -- $cv
    page=$("$bin" "$1" "$2" --help 2>"$errors")
    rc=$?
    if [ $rc -ne 0 ] || [ -s "$errors" ]; then
        echo "help_pages.sh: '$cv --help' exited $rc: $(cat "$errors")" >&2
        status=1
    elif [ "$page" != "$("$bin" "$1" --help)" ]; then
        echo "help_pages.sh: '$cv --help' is not the page of '$1 --help'" >&2
        status=1
    else
        echo "$cv: help page ok"
    fi
done
rm -f "$errors"
exit $status
