#!/bin/sh
# The market's role machines share no memory: no role module includes
# another role's header, nor the world or a driver that hosts them.
# Usage: role_includes.sh MARKET_DIR          check the tree
#        role_includes.sh MARKET_DIR --self   also show that the check fails on an injected include
set -eu
DIR=$1
ROLES="bgm_market_agent bgm_resource"
HOSTS="bgm_world bgm_evq bgm_sim bgm_simdriver bgm_platform"

check() {
    d=$1 bad=0 found=0
    for r in $ROLES; do
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
    cp "$DIR"/*.h "$DIR"/*.c "$tmp"/
    printf '#include "bgm_world.h"\n' >> "$tmp/bgm_market_agent.c"
    if check "$tmp" > /dev/null; then
        echo "FAIL: the check missed an injected #include \"bgm_world.h\""
        exit 1
    fi
fi
echo "role includes: ok ($ROLES)"
