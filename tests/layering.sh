#!/bin/sh
# The layers of the libraries, checked from the code's own #include lines:
#   1. no circle: within the project, the modules (x.h + x.c) and the
#      headers they include form no loop (tsort finds one if there is);
#   2. folders only look down: every include goes to a module of the same
#      folder or of a folder of a lower layer, never up nor sideways:
#        0  services/base  the shared base (bg_*)
#        1  services       the engine          1  market   the mechanisms
#        2  agents         daemons' libraries  3  broker   the broker's library
#        4  broker/cli     the biotgrid command (thin mains)
#      (services and market stand side by side and know nothing of each other.)
# Usage: layering.sh ROOT            check the tree
#        layering.sh ROOT --self     also show that the check fails on injected includes
set -eu
ROOT=$1

rank() {
    case $1 in
        services/base) echo 0 ;;
        services | market) echo 1 ;;
        agents) echo 2 ;;
        broker) echo 3 ;;
        broker/cli) echo 4 ;;
        *) echo "" ;;
    esac
}

# Prints "from-module from-folder to-module to-folder" for each include of a
# project header by a project file under dir $1.
edges() {
    tree=$1
    find "$tree/services" "$tree/market" "$tree/agents" "$tree/broker" \
        \( -name '*.c' -o -name '*.h' \) -type f | sort > "$work/files"
    sed -e "s#^$tree/##" "$work/files" | awk -F/ '{
        n = split($0, p, "/"); file = p[n]; dir = substr($0, 1, length($0) - length(file) - 1)
        print file, dir }' > "$work/where"
    while read -r path; do
        rel=${path#"$tree"/}
        from_dir=${rel%/*}
        from=$(basename "$rel"); from=${from%.*}
        sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*"\([^"]*\)".*/\1/p' "$path" |
            while read -r header; do
                to_dir=$(awk -v h="$(basename "$header")" '$1 == h { print $2; exit }' "$work/where")
                [ -n "$to_dir" ] || continue # a system or generated header
                to=$(basename "$header"); to=${to%.*}
                [ "$to" = "$from" ] && continue
                echo "$from $from_dir $to $to_dir"
            done
    done < "$work/files"
}

check() {
    tree=$1 bad=0
    edges "$tree" > "$work/edges"
    [ -s "$work/edges" ] || { echo "FAIL: no include read under $tree"; return 1; }
    # 1. circles: tsort names the modules of each loop it finds.
    if ! awk '{ print $1, $3 }' "$work/edges" | tsort > /dev/null 2> "$work/loops"; then
        echo "FAIL: include circle among: $(sed -n 's/^tsort: //p' "$work/loops" |
            grep -v 'input contains a loop' | tr '\n' ' ')"
        bad=1
    fi
    # 2. folders look down only.
    while read -r from from_dir to to_dir; do
        [ "$from_dir" = "$to_dir" ] && continue
        rf=$(rank "$from_dir") rt=$(rank "$to_dir")
        if [ -z "$rf" ] || [ -z "$rt" ]; then
            echo "FAIL: $from_dir/$from includes $to_dir/$to: a folder without a layer"
            bad=1
        elif [ "$rt" -ge "$rf" ]; then
            echo "FAIL: $from_dir/$from (layer $rf) includes $to_dir/$to.h (layer $rt)"
            bad=1
        fi
    done < "$work/edges"
    return $bad
}

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
check "$ROOT"
count=$(wc -l < "$work/edges")
if [ "${2:-}" = "--self" ]; then
    # Each injection must be caught: the two circles the engine once had,
    # includes that look up a layer (a library reaching for the command's
    # cmd.h among them) or sideways.
    for inject in "services/bg_scene.c bg_prepare.h" "services/bg_backend.c bg_surface_arap.h" \
                  "services/bg_mesh.c bga_backend.h" "market/bgm_seller.c bg_static.h" \
                  "broker/bgb_store.c cmd.h"; do
        set -- $inject
        copy=$work/tree
        rm -rf "$copy"
        mkdir -p "$copy"
        cp -R "$ROOT/services" "$ROOT/market" "$ROOT/agents" "$ROOT/broker" "$copy/"
        printf '#include "%s"\n' "$2" >> "$copy/$1"
        if (check "$copy" > /dev/null); then
            echo "FAIL: the check missed an injected #include \"$2\" in $1"
            exit 1
        fi
    done
    echo "layering: the check fails on each of 5 injected includes"
fi
echo "layering: ok ($count includes, no circle, every folder looks down)"
