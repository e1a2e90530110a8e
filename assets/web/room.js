// A lipcall room on Janus, from a browser, with Janus's own janus.js (Debian's
// libjs-janus-gateway). The room follows lipcall's conventions (src/net/janus/messages.rs):
// rooms are named by strings, the first member creates the room (Opus, up to 64 publishers)
// and the passphrase is the room's pin. We publish the microphone and subscribe to every other
// publisher, one subscription each, as lipcall does.
//
// The query string says where: ?room=ROOM&pin=PIN&name=NAME&janus=URL (janus defaults to port
// 8088 of the page's host; debug=1 turns on janus.js's own logging). Every event, and each
// second the packets and audio energy received per speaker, is logged to the console as one
// `lipcall-room: ...` line, for people and for tests (chromium --enable-logging=stderr).
'use strict';

const VIDEOROOM = 'janus.plugin.videoroom';
// VideoRoom error codes (janus_videoroom.c).
const NO_SUCH_ROOM = 426;
const ROOM_EXISTS = 427;
const INVALID_ELEMENT = 430;

const query = new URLSearchParams(location.search);
const config = {
  room: query.get('room'),
  pin: query.get('pin') || null,
  name: query.get('name') || 'browser',
  janus:
    query.get('janus') ||
    `${location.protocol}//${location.hostname || '127.0.0.1'}:${location.protocol === 'https:' ? 8089 : 8088}/janus`,
  debug: query.get('debug') === '1',
};

// A stock Janus numbers its rooms (string_ids unset): a room that is a number goes as one, and
// as a string where the server names rooms by strings, as lipcall does.
let roomId = /^[1-9][0-9]{0,14}$/.test(config.room || '') ? Number(config.room) : config.room;
let janus = null;
let publisher = null;
let myId = null;
let privateId = null;
let joined = false;
let triedCreate = false;
/** Remote publishers we subscribe to, by feed id. */
const feeds = new Map();

function log(line) {
  console.log(`lipcall-room: ${line}`);
}

function setStatus(text, isError) {
  const status = document.getElementById('status');
  status.textContent = text;
  status.classList.toggle('error', Boolean(isError));
}

function fail(reason) {
  log(`error ${reason}`);
  setStatus(reason, true);
}

function showForm() {
  const form = document.getElementById('join-form');
  form.elements.janus.value = config.janus;
  form.elements.name.value = config.name;
  form.hidden = false;
  setStatus('Give a room to join.');
}

function withPin(body) {
  if (config.pin) {
    body.pin = config.pin;
  }
  return body;
}

function start() {
  document.getElementById('room-name').textContent = `"${config.room}"`;
  Janus.init({
    debug: config.debug ? 'all' : false,
    dependencies: Janus.useDefaultDependencies(),
    callback: () => {
      if (!Janus.isWebrtcSupported()) {
        fail('this browser has no WebRTC');
        return;
      }
      setStatus(`Connecting to ${config.janus}...`);
      janus = new Janus({
        server: config.janus,
        success: attachPublisher,
        error: lost,
        destroyed: () => setStatus('Left the room.'),
      });
    },
  });
}

/** The session failed: at the start a wrong address; later Janus restarted or went away. */
function lost(error) {
  if (!joined) {
    fail(`cannot reach Janus at ${config.janus}: ${error}`);
    return;
  }
  log(`lost the room (${error}); rejoining`);
  setStatus('Lost the room; rejoining...', true);
  setTimeout(() => location.reload(), 2000);
}

function attachPublisher() {
  janus.attach({
    plugin: VIDEOROOM,
    success: (handle) => {
      publisher = handle;
      joinAsPublisher();
    },
    error: (error) => fail(`attaching the VideoRoom plugin: ${error}`),
    webrtcState: (up, reason) => {
      if (up) {
        log('publishing');
        setStatus(`In room "${config.room}" as ${config.name}, microphone on.`);
      } else {
        log(`not publishing (${reason || 'hung up'})`);
      }
    },
    onmessage: onPublisherMessage,
  });
}

function joinAsPublisher() {
  publisher.send({
    message: withPin({
      request: 'join',
      ptype: 'publisher',
      room: roomId,
      display: config.name,
    }),
  });
}

/** The first member creates the room, as lipcall does; then joins it. */
function createRoom() {
  triedCreate = true;
  publisher.send({
    message: withPin({
      request: 'create',
      room: roomId,
      description: `lipcall ${config.room}`,
      publishers: 64,
      audiocodec: 'opus',
      videocodec: 'vp8',
      notify_joining: true,
    }),
    success: (result) => {
      // Someone else may have created it in between: join theirs.
      if (result.error_code && result.error_code !== ROOM_EXISTS) {
        fail(`Janus VideoRoom error ${result.error_code}: ${result.error}`);
        return;
      }
      log(`created room ${JSON.stringify(config.room)}`);
      joinAsPublisher();
    },
    error: (error) => fail(`creating the room: ${error}`),
  });
}

function onPublisherMessage(msg, jsep) {
  if (msg.videoroom === 'joined') {
    joined = true;
    myId = msg.id;
    privateId = msg.private_id;
    log(`in room ${JSON.stringify(config.room)} as ${myId}`);
    setStatus(`In room "${config.room}" as ${config.name}; opening the microphone...`);
    publish();
    followPublishers(msg.publishers);
  } else if (msg.videoroom === 'event') {
    if (msg.error_code === NO_SUCH_ROOM && !triedCreate) {
      createRoom();
      return;
    }
    if (msg.error_code === INVALID_ELEMENT && !joined) {
      if (typeof roomId === 'number') {
        roomId = config.room;
        joinAsPublisher();
      } else {
        fail(`this Janus numbers its rooms: give the room as a number (Janus said: ${msg.error})`);
      }
      return;
    }
    if (msg.error_code) {
      fail(`Janus VideoRoom error ${msg.error_code}: ${msg.error}`);
      return;
    }
    followPublishers(msg.publishers);
    for (const gone of [msg.leaving, msg.unpublished]) {
      if (gone !== undefined && gone !== 'ok') {
        dropFeed(gone);
      }
    }
  }
  if (jsep) {
    publisher.handleRemoteJsep({ jsep });
  }
}

function publish() {
  publisher.createOffer({
    tracks: [{ type: 'audio', capture: true, recv: false }],
    success: (jsep) => {
      publisher.send({ message: { request: 'publish', display: config.name }, jsep });
    },
    error: (error) => fail(`microphone: ${error.message || error}`),
  });
}

function followPublishers(list) {
  for (const p of list || []) {
    if (p.id !== myId && !feeds.has(p.id)) {
      subscribe(p.id, p.display || String(p.id));
    }
  }
}

function subscribe(id, name) {
  const feed = { id, name, handle: null, row: addRow(name), audio: null };
  feeds.set(id, feed);
  log(`feed ${id} ${JSON.stringify(name)} is publishing; subscribing`);
  janus.attach({
    plugin: VIDEOROOM,
    success: (handle) => {
      feed.handle = handle;
      const body = withPin({
        request: 'join',
        ptype: 'subscriber',
        room: roomId,
        streams: [{ feed: id }],
      });
      if (privateId !== null && privateId !== undefined) {
        body.private_id = privateId;
      }
      handle.send({ message: body });
    },
    error: (error) => log(`feed ${id} cannot subscribe: ${error}`),
    onmessage: (msg, jsep) => {
      if (msg.error_code) {
        log(`feed ${id} Janus VideoRoom error ${msg.error_code}: ${msg.error}`);
        return;
      }
      if (jsep) {
        feed.handle.createAnswer({
          jsep,
          tracks: [],
          success: (answer) => {
            feed.handle.send({ message: { request: 'start', room: roomId }, jsep: answer });
          },
          error: (error) => log(`feed ${id} answer failed: ${error.message || error}`),
        });
      }
    },
    webrtcState: (up) => log(`feed ${id} ${JSON.stringify(name)} ${up ? 'connected' : 'hung up'}`),
    onremotetrack: (track, mid, on) => {
      if (track.kind !== 'audio') {
        return;
      }
      if (on && !feed.audio) {
        feed.audio = document.createElement('audio');
        feed.audio.autoplay = true;
        feed.audio.srcObject = new MediaStream([track]);
        document.getElementById('players').appendChild(feed.audio);
        feed.audio.play().catch((e) => log(`feed ${id} cannot play: ${e.message}`));
      }
    },
  });
}

/** A speaker left: its last counts are said, then its subscription is hung up. */
async function dropFeed(id) {
  const feed = feeds.get(id);
  if (!feed) {
    return;
  }
  feeds.delete(id);
  await reportFeed(feed).catch((e) => log(`stats: ${e.message}`));
  log(`feed ${id} ${JSON.stringify(feed.name)} left`);
  feed.row.remove();
  if (feed.audio) {
    feed.audio.remove();
  }
  if (feed.handle) {
    feed.handle.detach();
  }
}

function addRow(name) {
  const row = document.createElement('tr');
  for (const text of [name, '', '0', '0']) {
    const cell = document.createElement('td');
    cell.textContent = text;
    row.appendChild(cell);
  }
  const meter = document.createElement('meter');
  meter.max = 1;
  row.cells[1].appendChild(meter);
  document.getElementById('speakers').appendChild(row);
  return row;
}

async function statsOf(handle, type) {
  const pc = handle && handle.webrtcStuff && handle.webrtcStuff.pc;
  if (!pc) {
    return null;
  }
  let found = null;
  (await pc.getStats()).forEach((s) => {
    if (s.type === type && s.kind === 'audio') {
      found = s;
    }
  });
  return found;
}

async function reportFeed(feed) {
  const s = await statsOf(feed.handle, 'inbound-rtp');
  if (!s) {
    return;
  }
  const level = s.audioLevel || 0;
  feed.row.cells[1].firstChild.value = level;
  feed.row.cells[2].textContent = s.packetsReceived;
  feed.row.cells[3].textContent = s.packetsLost;
  log(
    `feed ${feed.id} ${JSON.stringify(feed.name)} packets=${s.packetsReceived} ` +
      `lost=${s.packetsLost} energy=${(s.totalAudioEnergy || 0).toFixed(6)} ` +
      `level=${level.toFixed(4)}`,
  );
}

/** Once a second: what each speaker's stream brought, and what our microphone sent. */
async function report() {
  for (const feed of feeds.values()) {
    await reportFeed(feed);
  }
  const sent = await statsOf(publisher, 'outbound-rtp');
  if (sent) {
    document.getElementById('sent').textContent = `${sent.packetsSent} packets sent`;
    log(`sent packets=${sent.packetsSent}`);
  }
}

if (config.room) {
  start();
  setInterval(() => report().catch((e) => log(`stats: ${e.message}`)), 1000);
} else {
  showForm();
}
