#!/usr/bin/env bash
# Here (not on the GPU machine, which has no git): snapshot trees for an A/B of prepared patches against HEAD, for
# ab_trees.sh's VARIANTS. Each tree is `git archive HEAD` of what ab_trees.sh runs, with the named patches applied.
#   bash benchmarks/train/patch_trees.sh DIR label=patch[+patch...] ...
# e.g. (session 35's two patches, each alone and both):
#   bash benchmarks/train/patch_trees.sh .s36 base= pw=activate_pointwise sh4=sh_colour_4lanes \
#        both=activate_pointwise+sh_colour_4lanes
# A patch name is a file benchmarks/train/results/*/NAME.patch. Prints the VARIANTS string to pass to ab_trees.sh.
set -eu
dir=$1; shift
mkdir -p "$dir"
variants=""
for spec in "$@"; do
  label=${spec%%=*}; patches=${spec#*=}
  tree=$dir/$label
  rm -rf "$tree" && mkdir -p "$tree"
  git archive HEAD gof_warp kernels configs tests benchmarks/render benchmarks/train | tar -x -C "$tree"
  for p in ${patches//+/ }; do
    file=$(ls benchmarks/train/results/*/"$p".patch | head -1)
    git apply --directory="$tree" "$file" 2>/dev/null || (cd "$tree" && patch -s -p1 < "$OLDPWD/$file")
  done
  variants="$variants $label:$tree"
done
echo "VARIANTS=\"${variants# }\""
