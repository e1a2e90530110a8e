#!/usr/bin/env bash
# Starts a PulseAudio server with one null sink ("vsink", monitor "vsink.monitor") for the
# real-time audio tests. The ALSA "pulse" plugin (libasound2-plugins) then makes ALSA's default
# device go through it. Safe to run twice. Works as root without --system. 48 kHz, the rate
# cpal opens the device at, so no resampler sits between our stream and the sink.
set -euo pipefail
if pactl info >/dev/null 2>&1; then
  pactl list short sinks | grep -q vsink \
    || pactl load-module module-null-sink sink_name=vsink rate=48000 >/dev/null
  pactl set-default-sink vsink
  exit 0
fi
pulseaudio --daemonize=yes --exit-idle-time=-1 -n \
  --load="module-null-sink sink_name=vsink rate=48000" \
  --load=module-native-protocol-unix 2>/dev/null
for _ in $(seq 50); do
  pactl info >/dev/null 2>&1 && break
  sleep 0.1
done
pactl set-default-sink vsink
pactl info | grep -E '^(Server String|Default Sink)'
