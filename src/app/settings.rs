//! Settings kept between runs: a small JSON file under the XDG config directory, readable by
//! its owner alone (it holds the SIP account's password).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::codec::any::Codec;
use crate::codec::opus::codec::Bandwidth;
use crate::net::janus::candidates::{IceServers, TurnServer};
use crate::net::sip::agent::{Account, SipError};
use crate::render::HeadVariant;

/// The codec new calls send unless the settings say otherwise: Opus. It is what the VoIP world
/// speaks today (WebRTC, SIP phones, Mumble, Discord), and it carries in-band FEC, so a lost
/// packet is rebuilt from the next one. Speex stays fully supported (and is the reference
/// path: its LSPs come straight from the bitstream); every peer may send any of the four.
pub const DEFAULT_CODEC: Codec = Codec::Opus;

/// What the receiver does with one peer (all local choices; nothing crosses the network).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PeerPrefs {
    /// Off: a still head, and no network runs for this peer.
    pub animate: bool,
    pub muted: bool,
    /// Linear gain, 0..=2.
    #[serde(deserialize_with = "number_or_nan")]
    pub volume: f32,
    /// The large close-up of the mouth.
    pub lipreading: bool,
    /// Viseme set: a count (2..=6 or 15) or names, as `--visemes` takes; empty: the
    /// network's own set (no re-projection).
    pub visemes: String,
    /// Jaw-from-energy instead of the network, for comparison.
    pub jaw: bool,
    /// Lip closures: -1 fewer (only the surest) .. 0 the model's balance .. 1 more (nearly
    /// every /p b m/, and more often where there is none); for lipreading.
    #[serde(deserialize_with = "number_or_nan")]
    pub closures: f32,
    /// The living face: blinks, glances and head motion with the voice (off: eyes and head
    /// still; the mouth keeps moving).
    pub life: bool,
    /// The head's look: a variant's name ([`crate::render::VARIANTS`]); empty: chosen by the
    /// peer's name.
    pub head: String,
}

impl Default for PeerPrefs {
    fn default() -> Self {
        Self {
            animate: true,
            muted: false,
            volume: 1.0,
            lipreading: false,
            visemes: String::new(),
            jaw: false,
            closures: 0.0,
            life: true,
            head: String::new(),
        }
    }
}

impl PeerPrefs {
    /// Every value in its range: a volume out of 0..=2 or a closure bias out of -1..=1 is
    /// clamped, one that is no number at all (NaN, infinity, `null`) is the default.
    fn sanitized(self) -> Self {
        let default = Self::default();
        let within = |v: f32, lo: f32, hi: f32, fallback: f32| {
            if v.is_finite() {
                v.clamp(lo, hi)
            } else {
                fallback
            }
        };
        Self {
            volume: within(self.volume, 0.0, 2.0, default.volume),
            closures: within(self.closures, -1.0, 1.0, default.closures),
            // A name no variant has (an older or hand-edited file) is the automatic choice.
            head: HeadVariant::by_name(&self.head)
                .map(|v| v.name.to_owned())
                .unwrap_or_default(),
            ..self
        }
    }
}

/// A number as f32 (NaN for `null`; beyond f32's range, its largest value), so that one odd
/// value costs that value and not the whole file; [`PeerPrefs::sanitized`] then puts it in range.
fn number_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
    let wide = f64::from(f32::MAX);
    Ok(Option::<f64>::deserialize(d)?.map_or(f32::NAN, |v| v.clamp(-wide, wide) as f32))
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Settings {
    pub name: String,
    pub last_address: String,
    pub last_room: String,
    /// Device ids from the pickers; empty means the default device.
    pub input_device: String,
    pub output_device: String,
    pub push_to_talk: bool,
    /// The codec we send in new calls.
    pub codec: Codec,
    /// The band Opus codes in new calls (fullband: up to 20 kHz).
    pub bandwidth: Bandwidth,
    /// Opus's frame length in new calls, ms: 20, or 10 (10 ms less delay, twice the packets;
    /// docs/audio.md argues the default).
    pub frame_ms: u8,
    /// Per-peer choices by display name (SSRCs change every call).
    pub peers: BTreeMap<String, PeerPrefs>,
    /// STUN and TURN servers for Janus rooms behind a NAT.
    pub nat: NatSettings,
    /// What a Janus that restricts its API asks for.
    pub janus: JanusCredentials,
    /// The SIP account the app registers with and takes phone calls on.
    pub sip: SipSettings,
    /// The port direct calls reach us on, on all interfaces (none: the first start picks one,
    /// [`crate::app::listen`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub listen_port: Option<u16>,
    /// Audio kept queued for the output beyond one device period, in ms: less answers
    /// sooner, more survives a busier machine (docs/audio.md has the numbers).
    pub output_margin_ms: u32,
}

/// The longest output margin taken from the settings or the command line.
pub const MAX_OUTPUT_MARGIN_MS: u32 = 200;

/// An output margin in ms as the playback takes it, capped at [`MAX_OUTPUT_MARGIN_MS`].
pub fn output_margin(ms: u32) -> std::time::Duration {
    std::time::Duration::from_millis(u64::from(ms.min(MAX_OUTPUT_MARGIN_MS)))
}

/// A Janus's `api_secret` and the token its admin stored for us (kept in the settings file,
/// which only its owner may read; never in `Debug` output).
#[derive(Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct JanusCredentials {
    pub api_secret: String,
    pub token: String,
}

impl std::fmt::Debug for JanusCredentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let said = |s: &str| if s.is_empty() { "" } else { "(set)" };
        f.debug_struct("JanusCredentials")
            .field("api_secret", &said(&self.api_secret))
            .field("token", &said(&self.token))
            .finish()
    }
}

/// The servers that take a Janus room's media across NATs (see docs/janus.md).
#[derive(Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct NatSettings {
    /// HOST:PORT; empty: none.
    pub stun: String,
    pub turn: String,
    pub turn_user: String,
    pub turn_password: String,
    /// All media through the TURN relay: the room never learns this machine's addresses.
    pub turn_only: bool,
}

impl std::fmt::Debug for NatSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NatSettings")
            .field("stun", &self.stun)
            .field("turn", &self.turn)
            .field("turn_user", &self.turn_user)
            .field("turn_only", &self.turn_only)
            .finish_non_exhaustive()
    }
}

impl NatSettings {
    /// The servers a call asks, blank fields left out.
    pub fn ice(&self) -> IceServers {
        let given = |s: &str| Some(s.trim().to_string()).filter(|s| !s.is_empty());
        let turn = given(&self.turn).map(|server| TurnServer {
            server,
            username: self.turn_user.trim().to_string(),
            password: self.turn_password.clone(),
        });
        IceServers {
            stun: given(&self.stun),
            relay_only: self.turn_only && turn.is_some(),
            turn,
        }
    }
}

/// A SIP account: who we are, where we register, and the password (kept in the settings file,
/// which only its owner may read; never in the log or in `Debug` output).
#[derive(Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct SipSettings {
    /// `sip:USER@DOMAIN`; empty: no account (the app neither registers nor takes SIP calls).
    pub account: String,
    /// `HOST[:PORT]` to register with, where it is not the account's domain.
    pub registrar: String,
    pub password: String,
    /// The local UDP port the phone listens on (0: any free one).
    pub local_port: u16,
    /// A PEM file of the authority that signed a TLS registrar's certificate, trusted beside
    /// the system's roots; empty: none.
    pub ca: String,
}

impl std::fmt::Debug for SipSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SipSettings")
            .field("account", &self.account)
            .field("registrar", &self.registrar)
            .field("local_port", &self.local_port)
            .field("ca", &self.ca)
            .field(
                "password",
                &if self.password.is_empty() {
                    ""
                } else {
                    "(set)"
                },
            )
            .finish()
    }
}

impl SipSettings {
    /// The account to register, none where no account is given.
    pub fn account(&self) -> Result<Option<Account>, SipError> {
        if self.account.trim().is_empty() {
            return Ok(None);
        }
        let mut account = Account::parse(&self.account, &self.password)?;
        let registrar = self.registrar.trim();
        account.registrar = (!registrar.is_empty()).then(|| registrar.to_owned());
        Ok(Some(account))
    }
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            name: std::env::var("USER").unwrap_or_else(|_| "me".into()),
            last_address: String::new(),
            last_room: String::new(),
            input_device: String::new(),
            output_device: String::new(),
            push_to_talk: false,
            codec: DEFAULT_CODEC,
            bandwidth: Bandwidth::Fullband,
            frame_ms: 20,
            peers: BTreeMap::new(),
            nat: NatSettings::default(),
            janus: JanusCredentials::default(),
            sip: SipSettings::default(),
            listen_port: None,
            output_margin_ms: crate::audio::DEFAULT_OUTPUT_MARGIN.as_millis() as u32,
        }
    }
}

/// `$XDG_CONFIG_HOME/lipcall/settings.json`, else `~/.config/lipcall/settings.json`.
pub fn default_path() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(base.join("lipcall").join("settings.json"))
}

impl Settings {
    /// Loads the settings; a missing or unusable file gives the defaults (and says why). A
    /// regular file that cannot be used (not JSON, over 1 MiB) is moved aside to
    /// `settings.json.bad` first, so the next save does not put defaults over what the user had.
    pub fn load(path: &Path) -> (Self, Option<String>) {
        use crate::input::InputError;
        // Settings are a few hundred bytes; a device or a huge file there is not read.
        let why = match crate::input::read_to_string(path, 1 << 20) {
            Ok(text) => match serde_json::from_str::<Self>(&text) {
                Ok(s) => return (s.sanitized(), None),
                Err(e) => format!("{}: ignored ({e})", path.display()),
            },
            Err(InputError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
                return (Self::default(), None);
            }
            Err(e @ InputError::NotRegular { .. }) => {
                return (Self::default(), Some(format!("settings ignored: {e}")));
            }
            Err(e) => format!("settings ignored: {e}"),
        };
        let aside = bad_copy_path(path);
        let note = match std::fs::rename(path, &aside) {
            Ok(()) => format!("{why}; the file is kept as {}", aside.display()),
            Err(e) => format!("{why}; cannot move it aside to {}: {e}", aside.display()),
        };
        (Self::default(), Some(note))
    }

    fn sanitized(mut self) -> Self {
        self.peers = std::mem::take(&mut self.peers)
            .into_iter()
            .map(|(name, prefs)| (name, prefs.sanitized()))
            .collect();
        self
    }

    /// Writes the settings (atomically: a new file renamed over the old), readable and
    /// writable by the owner alone. Only a regular file is replaced: a device or folder at
    /// the path is left alone, with an error.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
            return Err(std::io::Error::other("not a regular file; left as it is"));
        }
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        let tmp = path.with_extension("json.tmp");
        write_private(&tmp, text.as_bytes())?;
        std::fs::rename(&tmp, path)
    }
}

/// Writes a new file that only its owner can read (mode 0600 where there are modes): a stale
/// one is removed first, so that no looser mode is inherited from it.
fn write_private(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut file = options.open(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

/// Where an unusable settings file is kept: `settings.json.bad` beside it.
fn bad_copy_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".bad");
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_round_trip_and_bad_files_give_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub").join("settings.json");
        let mut s = Settings {
            name: "Ada".into(),
            ..Default::default()
        };
        s.peers.insert(
            "Bob".into(),
            PeerPrefs {
                animate: false,
                visemes: "3".into(),
                ..Default::default()
            },
        );
        s.save(&path).unwrap();
        assert_eq!(Settings::load(&path), (s, None));
        // Settings from before the living face: it is on.
        std::fs::write(
            &path,
            r#"{"peers": {"Bob": {"animate": true, "visemes": "3"}}}"#,
        )
        .unwrap();
        let (old, why) = Settings::load(&path);
        assert!(why.is_none() && old.peers["Bob"].life && old.peers["Bob"].visemes == "3");
        // Settings from before the codec choice: new calls send Opus; a choice is kept.
        assert_eq!(old.codec, Codec::Opus);
        std::fs::write(&path, r#"{"codec": "speex"}"#).unwrap();
        assert_eq!(Settings::load(&path).0.codec, Codec::Speex);
        std::fs::write(&path, "{not json").unwrap();
        let (d, why) = Settings::load(&path);
        assert_eq!(d, Settings::default());
        assert!(why.is_some());
        assert_eq!(Settings::load(&dir.path().join("none.json")), (d, None));
    }

    #[test]
    fn nat_servers_round_trip_and_the_password_is_not_in_debug_output() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        let s = Settings {
            nat: NatSettings {
                stun: " stun.example.org:3478 ".into(),
                turn: "turn.example.org:3478".into(),
                turn_user: "ann".into(),
                turn_password: "hunter2".into(),
                turn_only: true,
            },
            ..Default::default()
        };
        let s = Settings {
            janus: JanusCredentials {
                api_secret: "janus-hunter2".into(),
                token: "token-hunter2".into(),
            },
            ..s
        };
        s.save(&path).unwrap();
        assert_eq!(Settings::load(&path), (s.clone(), None));
        assert!(!format!("{s:?}").contains("hunter2"));
        let ice = s.nat.ice();
        assert_eq!(ice.stun.as_deref(), Some("stun.example.org:3478"));
        assert!(ice.relay_only);
        assert!(!format!("{ice:?}").contains("hunter2"));
        // No TURN server: nothing to relay through, whatever the box says.
        let none = NatSettings {
            turn_only: true,
            ..Default::default()
        };
        assert_eq!(none.ice(), IceServers::default());
    }

    #[test]
    fn an_unusable_file_is_kept_aside_not_saved_over() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        let aside = dir.path().join("settings.json.bad");
        for content in [
            "{\"name\": \"Ada\", oops".to_string(),
            " ".repeat((1 << 20) + 1),
        ] {
            std::fs::write(&path, &content).unwrap();
            let (loaded, why) = Settings::load(&path);
            let why = why.unwrap();
            assert!(why.contains("settings.json.bad"), "{why}");
            // What the app does on exit.
            loaded.save(&path).unwrap();
            assert_eq!(std::fs::read_to_string(&aside).unwrap(), content);
            assert_eq!(Settings::load(&path), (Settings::default(), None));
        }
    }

    #[test]
    fn the_frame_length_is_kept_and_defaults_to_20_ms() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        std::fs::write(&path, r#"{"name": "Ada"}"#).unwrap();
        assert_eq!(Settings::load(&path).0.frame_ms, 20);
        let ten = Settings {
            frame_ms: 10,
            ..Settings::default()
        };
        ten.save(&path).unwrap();
        assert_eq!(Settings::load(&path).0.frame_ms, 10);
        let spec = |frame_ms| crate::app::engine::CallSpec {
            frame_ms,
            ..Default::default()
        };
        assert_eq!(spec(10).encoder_settings().opus.frame_ms, 10);
        // A length the encoder does not take (an edited file) sends 20 ms frames.
        assert_eq!(spec(15).encoder_settings().opus.frame_ms, 20);
    }

    #[test]
    fn the_output_margin_defaults_for_an_older_file_and_is_capped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        std::fs::write(&path, r#"{"name": "Ada"}"#).unwrap();
        let (s, why) = Settings::load(&path);
        assert!(why.is_none(), "{why:?}");
        assert_eq!(s.output_margin_ms, 5);
        std::fs::write(&path, r#"{"output_margin_ms": 40}"#).unwrap();
        assert_eq!(Settings::load(&path).0.output_margin_ms, 40);
        assert_eq!(output_margin(40), std::time::Duration::from_millis(40));
        assert_eq!(
            output_margin(u32::MAX),
            std::time::Duration::from_millis(200)
        );
    }

    #[test]
    fn an_odd_number_costs_that_number_not_every_setting() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        std::fs::write(
            &path,
            r#"{"name": "Ada", "peers": {"Bob": {"volume": 1e39, "closures": -7, "muted": true},
                "Cy": {"volume": null, "closures": 0.5, "head": "fair, BLOND"},
                "Di": {"volume": -3, "head": "Nobody's head"}}}"#,
        )
        .unwrap();
        let (s, why) = Settings::load(&path);
        assert!(why.is_none(), "{why:?}");
        assert_eq!(s.name, "Ada");
        let bob = &s.peers["Bob"];
        assert!(
            bob.muted && bob.volume == 2.0 && bob.closures == -1.0,
            "{bob:?}"
        );
        assert_eq!((s.peers["Cy"].volume, s.peers["Cy"].closures), (1.0, 0.5));
        assert_eq!(s.peers["Di"].volume, 0.0);
        // A head by any case is the variant's name; one no variant has is the automatic one.
        assert_eq!(s.peers["Cy"].head, "Fair, blond");
        assert_eq!(s.peers["Di"].head, "");
        // Saved and loaded again: the same, every other setting kept.
        s.save(&path).unwrap();
        assert!(!std::fs::read_to_string(&path).unwrap().contains("null"));
        assert_eq!(Settings::load(&path), (s, None));
    }

    #[test]
    fn the_sip_password_is_kept_private_and_never_printed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.json");
        // An old file anyone could read, and a stale temporary one.
        std::fs::write(&path, "{}").unwrap();
        std::fs::write(path.with_extension("json.tmp"), "{}").unwrap();
        let s = Settings {
            sip: SipSettings {
                account: "sip:alice@pbx.example".into(),
                registrar: "127.0.0.1:5070".into(),
                password: "hunter2-secret".into(),
                ..SipSettings::default()
            },
            ..Settings::default()
        };
        s.save(&path).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&path).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600, "{mode:o}");
        }
        assert_eq!(Settings::load(&path), (s.clone(), None));
        for shown in [format!("{s:?}"), format!("{:?}", s.sip.account().unwrap())] {
            assert!(!shown.contains("hunter2"), "{shown}");
            assert!(shown.contains("alice"), "{shown}");
        }
        let account = s.sip.account().unwrap().unwrap();
        assert_eq!(
            (account.user.as_str(), account.registrar()),
            ("alice", "127.0.0.1:5070")
        );
        assert_eq!(account.password, "hunter2-secret");
        assert_eq!(SipSettings::default().account(), Ok(None));
        let bad = SipSettings {
            account: "alice".into(),
            ..SipSettings::default()
        };
        assert!(bad.account().is_err());
    }

    #[test]
    fn a_device_as_the_settings_file_is_not_read_nor_replaced() {
        let (s, why) = Settings::load(Path::new("/dev/zero"));
        assert_eq!(s, Settings::default());
        let why = why.unwrap();
        assert!(why.contains("not a regular file"), "{why}");
        let dir = tempfile::tempdir().unwrap();
        assert!(s.save(dir.path()).is_err());
        assert!(dir.path().is_dir());
    }
}
