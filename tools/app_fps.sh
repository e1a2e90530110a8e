#!/usr/bin/env bash
# UI frame rate of the app with N talking peers (N `lipcall send` callers on
# loopback), read from its --status counters under Xvfb on whatever adapter wgpu finds
# (the software one on a machine without a GPU).
#   tools/app_fps.sh [PEERS=1] [SECONDS=20] [LIPCALL=target/release/lipcall]
set -euo pipefail
peers=${1:-1}
seconds=${2:-20}
lipcall=${3:-target/release/lipcall}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$work/xdg}
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
port=$((20000 + RANDOM % 20000))
# The callers talk for the whole run: the demo speech, looped.
sox assets/speech/demo.wav assets/speech/demo.wav assets/speech/demo.wav assets/speech/demo.wav \
    assets/speech/demo.wav "$work/speech.wav"
cat >"$work/run.sh" <<INNER
#!/usr/bin/env bash
"$lipcall" --no-audio --listen 127.0.0.1:$port --quit-after $((seconds + 15)) \
    --status "$work/status.txt" --settings "$work/settings.json" >"$work/app.log" 2>&1 &
app=\$!
sleep 2
senders=
for i in \$(seq 1 $peers); do
    "$lipcall" send "$work/speech.wav" --to 127.0.0.1:$port --name "caller \$i" >/dev/null 2>&1 &
    senders="\$senders \$!"
done
sleep 2
head -1 "$work/status.txt" >"$work/start.txt"
cut -d' ' -f14,15 /proc/\$app/stat >"$work/cpu_start.txt"
sleep $seconds
cp "$work/status.txt" "$work/end.txt"
cut -d' ' -f14,15 /proc/\$app/stat >"$work/cpu_end.txt"
# The app quits by itself a while later; the margin keeps a loaded machine's slow start from
# ending it before the last reading.
kill \$app \$senders
wait || true
INNER
chmod +x "$work/run.sh"
xvfb-run -a -s "-screen 0 1600x900x24" "$work/run.sh"
field() { sed -n "s/.*\b$1=\([0-9.]*\).*/\1/p" "$2"; }
t0=$(field time_s "$work/start.txt"); t1=$(field time_s "$work/end.txt")
f0=$(field ui_frames "$work/start.txt"); f1=$(field ui_frames "$work/end.txt")
d0=$(field tiles_drawn "$work/start.txt"); d1=$(field tiles_drawn "$work/end.txt")
# CPU time of the app (all its threads, the software rasteriser's included) per UI frame: a
# figure that holds when other work shares the cores, unlike frames per second.
ticks=$(getconf CLK_TCK)
cpu_ms=$(awk -v hz="$ticks" 'NR==FNR { a = $1 + $2; next } { b = $1 + $2 } END { print (b - a) * 1000 / hz }' \
    "$work/cpu_start.txt" "$work/cpu_end.txt")
talking=$(grep -c "talking=true" "$work/end.txt" || true)
shown=$(grep -c "^peer " "$work/end.txt" || true)
awk -v p="$peers" -v t="$talking" -v s="$shown" -v t0="$t0" -v t1="$t1" -v f0="$f0" -v f1="$f1" -v d0="$d0" -v d1="$d1" -v c="$cpu_ms" \
    'BEGIN { printf "peers=%d shown=%d talking=%d ui_fps=%.1f head_renders_per_s=%.1f cpu_ms_per_ui_frame=%.1f\n", p, s, t, (f1-f0)/(t1-t0), (d1-d0)/(t1-t0), c/(f1-f0) }'
