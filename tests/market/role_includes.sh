#!/bin/sh
# The market's role machines share no memory: no role module includes
# another role's header, nor the world or a driver that hosts them. The
# modules role machines embed (the buying half, the seller's bargains)
# include neither a role's header nor a host's.
# Usage: role_includes.sh MARKET_DIR          check the tree
#        role_includes.sh MARKET_DIR --self   also show that the check fails on an injected include
set -eu
DIR=$1
ROLES="bgm_market_agent bgm_resource bgm_seller bgm_buyer"
EMBEDDED="bgm_purchase bgm_session"
HOSTS="bgm_world bgm_evq bgm_sim bgm_simdriver bgm_platform"

check() {
    d=$1 bad=0 found=0
    for r in $ROLES $EMBEDDED; do
        for f in "$d/$r.h" "$d/$r.c"; do
            [ -f "$f" ] || { echo "FAIL: $f missing"; return 1; }
            found=$((found + 1))
            for other in $ROLES $HOSTS; do
                [ "$other" = "$r" ] && continue
                if grep -Eq "^[[:space:]]*#[[:space:]]*include[[:space:]]*[\"<]$other\.h[\">]" "$f"; then
                    echo "FAIL: $(basename "$f") includes $other.h"
                    bad=1
                fi
            done
        done
    done
    [ "$found" -gt 0 ] || { echo "FAIL: no role module found"; return 1; }
    return $bad
}

check "$DIR"
if [ "${2:-}" = "--self" ]; then
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    for inject in "bgm_market_agent.c bgm_world.h" "bgm_buyer.c bgm_seller.h" \
                  "bgm_purchase.h bgm_buyer.h"; do
        set -- $inject
        rm -f "$tmp"/*
        cp "$DIR"/*.h "$DIR"/*.c "$tmp"/
        printf '#include "%s"\n' "$2" >> "$tmp/$1"
        if check "$tmp" > /dev/null; then
            echo "FAIL: the check missed an injected #include \"$2\" in $1"
            exit 1
        fi
    done
fi
echo "role includes: ok ($ROLES; embedded: $EMBEDDED)"
