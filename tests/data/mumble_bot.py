"""A third-party Mumble client for the tests: a pymumble bot (PyPI's pymumble, which speaks
through the TCP tunnel). It joins, says a 48 kHz mono WAV in real time, then listens and writes
what it heard from each user as 48 kHz WAVs.

usage: mumble_bot.py HOST PORT NAME SAY.wav OUT_PREFIX LISTEN_SECONDS
"""
import sys
import time
import wave

import pymumble_py3 as pymumble
from pymumble_py3.constants import PYMUMBLE_CLBK_SOUNDRECEIVED

host, port, name, say, out_prefix, listen = sys.argv[1:7]
mumble = pymumble.Mumble(host, name, port=int(port), reconnect=False)
mumble.set_receive_sound(True)
heard = {}


def on_sound(user, chunk):
    heard.setdefault(user["name"], bytearray()).extend(chunk.pcm)


mumble.callbacks.set_callback(PYMUMBLE_CLBK_SOUNDRECEIVED, on_sound)
mumble.start()
mumble.is_ready()
print("ready", flush=True)

with wave.open(say) as w:
    assert w.getframerate() == 48000 and w.getnchannels() == 1 and w.getsampwidth() == 2
    pcm = w.readframes(w.getnframes())
step = 48000 * 2 // 50
for i in range(0, len(pcm), step):
    mumble.sound_output.add_sound(pcm[i:i + step])
    while mumble.sound_output.get_buffer_size() > 0.2:
        time.sleep(0.01)
while mumble.sound_output.get_buffer_size() > 0:
    time.sleep(0.02)
print("spoke", flush=True)

end = time.time() + float(listen)
while time.time() < end:
    time.sleep(0.05)
for who, data in heard.items():
    with wave.open(f"{out_prefix}-{who}.wav", "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(48000)
        w.writeframes(bytes(data))
    print(f"heard {who} {len(data) / 96000:.2f}", flush=True)
mumble.stop()
