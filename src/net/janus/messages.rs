//! Janus API and VideoRoom messages as JSON values, and what lipcall reads out of Janus's
//! answers and events. No I/O: [`super::http`] carries them.
//!
//! A VideoRoom names rooms and publishers by positive integers (Janus's default) or, with its
//! `string_ids`, by strings (the repository's config). lipcall holds every id as a string and
//! sends it as the server's [`IdKind`] wants it.

use serde_json::{Value, json};

use super::JanusError;

pub const VIDEOROOM: &str = "janus.plugin.videoroom";

/// VideoRoom error codes lipcall reacts to (janus_videoroom.c).
pub const NO_SUCH_ROOM: i64 = 426;
pub const ROOM_EXISTS: i64 = 427;
/// A field of the wrong JSON type: a room id as a string where Janus wants a number, or the
/// other way round.
pub const INVALID_ELEMENT: i64 = 430;
/// Janus core: the session is gone (expired, or Janus restarted).
pub const NO_SUCH_SESSION: i64 = 458;

/// What a Janus that restricts its API asks of every request: its `api_secret`, and a token
/// its admin stored (`token_auth`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JanusAuth {
    pub api_secret: Option<String>,
    pub token: Option<String>,
}

impl JanusAuth {
    /// `request` with the credentials Janus reads from every request.
    pub fn sign(&self, mut request: Value) -> Value {
        if let Some(secret) = &self.api_secret {
            request["apisecret"] = json!(secret);
        }
        if let Some(token) = &self.token {
            request["token"] = json!(token);
        }
        request
    }

    /// The same, as the query of a long poll (a GET has no body).
    pub fn query(&self) -> Vec<(&'static str, &str)> {
        let mut q = Vec::new();
        if let Some(secret) = &self.api_secret {
            q.push(("apisecret", secret.as_str()));
        }
        if let Some(token) = &self.token {
            q.push(("token", token.as_str()));
        }
        q
    }
}

pub fn create_session(transaction: &str) -> Value {
    json!({ "janus": "create", "transaction": transaction })
}

pub fn attach(transaction: &str, plugin: &str) -> Value {
    json!({ "janus": "attach", "plugin": plugin, "transaction": transaction })
}

pub fn keepalive(transaction: &str) -> Value {
    json!({ "janus": "keepalive", "transaction": transaction })
}

pub fn detach(transaction: &str) -> Value {
    json!({ "janus": "detach", "transaction": transaction })
}

pub fn destroy(transaction: &str) -> Value {
    json!({ "janus": "destroy", "transaction": transaction })
}

/// A plugin message, with an SDP offer or answer when `jsep` is given.
pub fn message(transaction: &str, body: Value, jsep: Option<(&str, &str)>) -> Value {
    let mut m = json!({ "janus": "message", "transaction": transaction, "body": body });
    if let Some((kind, sdp)) = jsep {
        m["jsep"] = json!({ "type": kind, "sdp": sdp });
    }
    m
}

/// Our candidates are all in the SDP: gathering is complete when it is sent.
pub fn trickle_completed(transaction: &str) -> Value {
    json!({ "janus": "trickle", "transaction": transaction, "candidate": { "completed": true } })
}

/// How a VideoRoom spells its room, publisher and feed ids.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IdKind {
    /// Positive integers: Janus's default (`string_ids = false`).
    Numbers,
    /// Strings (`string_ids = true`).
    Strings,
}

impl IdKind {
    /// What to try first for a room given as `room`: a number where it is one.
    pub fn guess(room: &str) -> Self {
        match room.trim().parse::<u64>() {
            Ok(n) if n > 0 => Self::Numbers,
            _ => Self::Strings,
        }
    }

    /// `id` as this server wants it; `None` where a numbering server cannot name it.
    pub fn id(self, id: &str) -> Option<Value> {
        match self {
            Self::Strings => Some(Value::String(id.to_string())),
            Self::Numbers => match id.trim().parse::<u64>() {
                Ok(n) if n > 0 => Some(Value::from(n)),
                _ => None,
            },
        }
    }
}

/// A room for voices: Opus only, no video, many publishers.
pub fn create_room(room: &Value, pin: Option<&str>) -> Value {
    let mut body = json!({
        "request": "create",
        "room": room,
        "description": format!("lipcall {room}"),
        "publishers": 64,
        "audiocodec": "opus",
        "videocodec": "vp8",
        "notify_joining": true,
    });
    if let Some(pin) = pin {
        body["pin"] = json!(pin);
    }
    body
}

pub fn join_publisher(room: &Value, display: &str, pin: Option<&str>) -> Value {
    let mut body = json!({
        "request": "join", "ptype": "publisher", "room": room, "display": display,
    });
    if let Some(pin) = pin {
        body["pin"] = json!(pin);
    }
    body
}

pub fn publish(display: &str) -> Value {
    json!({ "request": "publish", "audio": true, "video": false, "data": false, "display": display })
}

pub fn join_subscriber(
    room: &Value,
    feed: &Value,
    private_id: Option<&Value>,
    pin: Option<&str>,
) -> Value {
    let mut body = json!({
        "request": "join", "ptype": "subscriber", "room": room,
        "streams": [{ "feed": feed }],
    });
    if let Some(id) = private_id {
        body["private_id"] = id.clone();
    }
    if let Some(pin) = pin {
        body["pin"] = json!(pin);
    }
    body
}

pub fn start() -> Value {
    json!({ "request": "start" })
}

/// The longest publisher id or display name lipcall takes (as RTCP caps a name).
pub const MAX_NAME_BYTES: usize = 64;

/// An id that may be a number or (with `string_ids`) a string, as a string; `None` for one no
/// summary line could print (control characters, longer than [`MAX_NAME_BYTES`]).
pub fn id_string(v: &Value) -> Option<String> {
    match v {
        Value::String(s)
            if !s.is_empty() && s.len() <= MAX_NAME_BYTES && !s.chars().any(char::is_control) =>
        {
            Some(s.clone())
        }
        Value::Number(n) => Some(n.to_string()),
        _ => None,
    }
}

/// A display name as lipcall shows it: control characters replaced, at most
/// [`MAX_NAME_BYTES`] bytes (cut at a character boundary).
pub fn display_name(name: &str) -> String {
    let mut shown = String::new();
    for c in name.chars() {
        let c = if c.is_control() { '\u{fffd}' } else { c };
        if shown.len() + c.len_utf8() > MAX_NAME_BYTES {
            break;
        }
        shown.push(c);
    }
    shown
}

/// Janus's own error (`"janus": "error"`) as an error, other answers unchanged.
pub fn check(reply: Value) -> Result<Value, JanusError> {
    if reply["janus"] == "error" {
        let e = &reply["error"];
        return Err(JanusError::Janus {
            code: e["code"].as_i64().unwrap_or(0),
            reason: e["reason"]
                .as_str()
                .unwrap_or("(no reason given)")
                .to_string(),
        });
    }
    Ok(reply)
}

/// The `data.id` of a `success` answer (a new session or handle).
pub fn success_id(reply: &Value) -> Result<u64, JanusError> {
    if reply["janus"] != "success" {
        return Err(JanusError::Protocol(format!(
            "expected success, got {reply}"
        )));
    }
    reply["data"]["id"]
        .as_u64()
        .ok_or_else(|| JanusError::Protocol(format!("no id in {reply}")))
}

/// The plugin's data in an answer or event, with the plugin's own error turned into one.
pub fn plugin_data(reply: &Value) -> Result<&Value, JanusError> {
    let data = &reply["plugindata"]["data"];
    if data.is_null() {
        return Err(JanusError::Protocol(format!("no plugin data in {reply}")));
    }
    if let Some(code) = data["error_code"].as_i64() {
        return Err(JanusError::Plugin {
            code,
            reason: data["error"]
                .as_str()
                .unwrap_or("(no reason given)")
                .to_string(),
        });
    }
    Ok(data)
}

/// The SDP of an answer or event's `jsep`, when it has one of `kind` ("offer", "answer").
pub fn jsep_sdp<'a>(reply: &'a Value, kind: &str) -> Option<&'a str> {
    let jsep = &reply["jsep"];
    (jsep["type"] == kind)
        .then(|| jsep["sdp"].as_str())
        .flatten()
}

/// A publisher in the room that sends audio.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Publisher {
    pub id: String,
    pub display: String,
}

/// What a VideoRoom event says about the room.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RoomNews {
    /// Publishers now sending (the list of a `joined` answer, or new ones).
    pub publishers: Vec<Publisher>,
    /// Publishers that stopped sending or left.
    pub gone: Vec<String>,
}

/// Room news in a VideoRoom event (`joined` or `event`); empty for anything else.
pub fn room_news(data: &Value) -> RoomNews {
    let mut news = RoomNews::default();
    if let Some(list) = data["publishers"].as_array() {
        for p in list {
            let Some(id) = id_string(&p["id"]) else {
                continue;
            };
            // Janus 1.x lists streams; a publisher with no audio stream has nothing for us.
            let has_audio = match p["streams"].as_array() {
                Some(streams) => streams
                    .iter()
                    .any(|s| s["type"] == "audio" && s["disabled"] != true),
                None => p["audio_codec"].is_string(),
            };
            if has_audio {
                news.publishers.push(Publisher {
                    id,
                    display: display_name(p["display"].as_str().unwrap_or("")),
                });
            }
        }
    }
    for key in ["leaving", "unpublished", "kicked"] {
        // `"leaving": "ok"` answers our own leave; only ids name others.
        if let Some(id) = id_string(&data[key])
            && data[key] != "ok"
        {
            news.gone.push(id);
        }
    }
    news
}

/// The Opus payload type an SDP maps (`a=rtpmap:PT opus/48000/2`).
pub fn opus_payload_type(sdp: &str) -> Option<u8> {
    sdp.lines().find_map(|line| {
        let rest = line.trim().strip_prefix("a=rtpmap:")?;
        let (pt, codec) = rest.split_once(' ')?;
        codec
            .to_ascii_lowercase()
            .starts_with("opus/48000")
            .then(|| pt.parse().ok())
            .flatten()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_carry_code_and_reason() {
        let e =
            check(json!({"janus": "error", "error": {"code": 458, "reason": "No such session 1"}}))
                .unwrap_err();
        assert!(matches!(e, JanusError::Janus { code: 458, .. }));
        assert_eq!(e.to_string(), "Janus error 458: No such session 1");
        let event = json!({"janus": "event", "plugindata": {"plugin": VIDEOROOM, "data": {
            "videoroom": "event", "error_code": 433, "error": "Unauthorized (wrong pin)"}}});
        let e = plugin_data(&event).unwrap_err();
        assert!(matches!(e, JanusError::Plugin { code: 433, .. }));
        assert_eq!(
            e.to_string(),
            "Janus VideoRoom error 433: Unauthorized (wrong pin)"
        );
    }

    #[test]
    fn room_news_lists_audio_publishers_and_departures() {
        let joined = json!({"videoroom": "joined", "room": "r", "id": "a", "publishers": [
            {"id": "b", "display": "Bea", "streams": [{"type": "audio", "mid": "0", "codec": "opus"}]},
            {"id": "c", "display": "Cam", "streams": [{"type": "video", "mid": "0"}]},
            {"id": 7, "display": "Old", "audio_codec": "opus"},
        ]});
        let news = room_news(&joined);
        let ids: Vec<&str> = news.publishers.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(ids, ["b", "7"]);
        assert_eq!(news.publishers[0].display, "Bea");
        assert_eq!(room_news(&json!({"leaving": "b"})).gone, ["b"]);
        assert_eq!(room_news(&json!({"unpublished": 7})).gone, ["7"]);
        assert!(room_news(&json!({"leaving": "ok"})).gone.is_empty());
    }

    #[test]
    fn opus_payload_type_from_sdp() {
        let sdp = "v=0\r\nm=audio 9 UDP/TLS/RTP/SAVPF 111 0\r\na=rtpmap:0 PCMU/8000\r\n\
                   a=rtpmap:111 opus/48000/2\r\n";
        assert_eq!(opus_payload_type(sdp), Some(111));
        assert_eq!(opus_payload_type("m=audio 9 RTP/AVP 0\r\n"), None);
    }

    #[test]
    fn messages_have_their_fields() {
        let m = message(
            "t1",
            join_publisher(&json!("room"), "Ann", Some("pw")),
            None,
        );
        assert_eq!(m["body"]["pin"], "pw");
        assert_eq!(m["body"]["display"], "Ann");
        assert!(m.get("jsep").is_none());
        let m = message("t2", publish("Ann"), Some(("offer", "v=0")));
        assert_eq!(m["jsep"]["type"], "offer");
        let s = join_subscriber(&json!("room"), &json!("b"), Some(&json!(123)), None);
        assert_eq!(s["streams"][0]["feed"], "b");
        assert_eq!(s["private_id"], 123);
    }

    #[test]
    fn ids_are_sent_as_the_server_numbers_them() {
        assert_eq!(IdKind::guess("1234"), IdKind::Numbers);
        assert_eq!(IdKind::guess("lipcall-test"), IdKind::Strings);
        assert_eq!(IdKind::guess("0"), IdKind::Strings);
        assert_eq!(IdKind::Numbers.id("1234"), Some(json!(1234)));
        assert_eq!(IdKind::Numbers.id("room"), None);
        assert_eq!(IdKind::Strings.id("1234"), Some(json!("1234")));
        let m = join_publisher(&IdKind::Numbers.id("1234").unwrap(), "Ann", None);
        assert!(m["room"].is_u64(), "{m}");
    }

    #[test]
    fn hostile_ids_and_names_are_refused_or_cut() {
        let news = room_news(&json!({"publishers": [
            {"id": "a\r\nlipcall: fake line", "display": "X", "audio_codec": "opus"},
            {"id": "x".repeat(100), "display": "Y", "audio_codec": "opus"},
            {"id": "b", "display": format!("Bea\n{}", "z".repeat(100_000)), "audio_codec": "opus"},
            {"id": "c", "display": "Zoë".repeat(30), "audio_codec": "opus"},
        ]}));
        let ids: Vec<&str> = news.publishers.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(ids, ["b", "c"]);
        let bea = &news.publishers[0].display;
        assert!(
            bea.starts_with("Bea\u{fffd}zz") && bea.len() <= MAX_NAME_BYTES,
            "{bea}"
        );
        let zoe = &news.publishers[1].display;
        assert!(zoe.len() <= MAX_NAME_BYTES && zoe.ends_with('ë'), "{zoe}");
        assert!(room_news(&json!({"leaving": "q\u{0}"})).gone.is_empty());
    }
}
