# Where a CUDA `whitted render` process spends its time on the GPU host, with and without
# Python bytecode (run there from the repository root: `bash lab/probes/ttfi_bytecode.sh`;
# profiles and -X importtime output to $OUT).
[ -e .whl ] || ln -s .whl-lite .whl; bash ci/device.sh py -c pass
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1; P=/opt/torch/.venv/bin/python3
env | grep -i '^python'; nproc; uptime
R="-m whitted render --backend cuda --size 1024x1024 --out /tmp/o --overwrite"
export WHITTED_CACHE=/tmp/wc
for s in bunny_1m conference; do for i in 1 2 3; do
  t0=$EPOCHREALTIME; $P $R scenes/$s.toml | grep timing; t1=$EPOCHREALTIME; echo "$s run $i wall $(python3 -c "print(round($t1-$t0,3))")"; done; done
$P -X importtime $R scenes/bunny_1m.toml 2> $OUT/imp_nobytecode.txt | grep timing
( unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc
  for i in 1 2 3; do t0=$EPOCHREALTIME; $P $R scenes/bunny_1m.toml | grep timing; t1=$EPOCHREALTIME; echo "bytecode run $i wall $(python3 -c "print(round($t1-$t0,3))")"; done
  for s in bunny_1m conference; do rm -rf /tmp/wcx; for i in cold cached; do
    t0=$EPOCHREALTIME; WHITTED_CACHE=/tmp/wcx $P $R scenes/$s.toml | grep timing; t1=$EPOCHREALTIME; echo "bytecode $s $i wall $(python3 -c "print(round($t1-$t0,3))")"; done; done
  $P -X importtime $R scenes/bunny_1m.toml 2> $OUT/imp_bytecode.txt | grep timing
  for s in bunny_1m conference; do rm -rf /tmp/wc2
    WHITTED_CACHE=/tmp/wc2 $P lab/probes/ttfi_profile.py scenes/$s.toml cuda --top 30 --frame 1024 > $OUT/prof_${s}_cold.txt 2>&1
    WHITTED_CACHE=/tmp/wc2 $P lab/probes/ttfi_profile.py scenes/$s.toml cuda --top 30 --frame 1024 > $OUT/prof_${s}_cached.txt 2>&1
    WHITTED_CACHE=/tmp/wc2 $P lab/probes/ttfi_profile.py scenes/$s.toml cuda --top 30 --cumulative > $OUT/prof_${s}_cached_cum.txt 2>&1
  done )
