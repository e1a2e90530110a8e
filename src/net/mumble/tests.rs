//! The client core against a scripted server: the join, channels and users, voice by UDP and
//! through the tunnel, nonce resynchronisation, and a hostile server's bytes.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use proptest::prelude::*;

use super::client::{ClientConfig, ClientCore, ClientEvent, SERVER_SILENT};
use super::crypt::CryptState;
use super::events::{NEWS_PER_WINDOW, NEWS_WINDOW};
use super::messages::{
    self, ChannelState, CryptSetup, Deframer, Incoming, MessageType, ServerSync, UserRemove,
    UserState,
};
use super::presence::{MAX_USERS, SELF_MUTE_EVERY};
use super::speakers::{MAX_DEPARTED, MAX_SPEAKERS};
use super::voice;
use crate::net::jitter::JitterConfig;
use crate::net::transport::PeerId;

const KEY: [u8; 16] = [7; 16];
const OURS: [u8; 16] = [1; 16];
const THEIRS: [u8; 16] = [2; 16];

fn server() -> SocketAddr {
    ([127, 0, 0, 1], 64738).into()
}

fn config(channel: Option<&str>, tcp_only: bool) -> ClientConfig {
    ClientConfig {
        name: "me".into(),
        password: Some("pw".into()),
        channel: channel.map(str::to_string),
        jitter: JitterConfig::default(),
        tcp_only,
    }
}

/// What the client sent on the TLS stream, decoded (type, body).
fn sent(core: &mut ClientCore) -> Vec<(u16, Vec<u8>)> {
    let mut d = Deframer::default();
    while let Some(bytes) = core.poll_control() {
        d.push(&bytes);
    }
    std::iter::from_fn(|| d.next_frame().unwrap()).collect()
}

/// What the client reports, who came and went included.
fn events(core: &mut ClientCore) -> Vec<ClientEvent> {
    core.report_presence(Instant::now());
    std::iter::from_fn(|| core.poll_event()).collect()
}

fn user(session: u32, name: &str, channel: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserState,
        &UserState {
            session: Some(session),
            name: Some(name.into()),
            channel_id: Some(channel),
            ..Default::default()
        },
    )
}

/// A client joined as session 3 in Root (channel 0), with Lobby (1) beside it, Bob (5) in
/// Root and Cy (6) in Lobby.
fn joined(now: Instant, channel: Option<&str>, tcp_only: bool) -> ClientCore {
    let mut core = ClientCore::new(config(channel, tcp_only), server(), now);
    core.connected(now);
    let mut stream = messages::frame(
        MessageType::CryptSetup,
        &CryptSetup {
            key: Some(KEY.to_vec()),
            client_nonce: Some(OURS.to_vec()),
            server_nonce: Some(THEIRS.to_vec()),
        },
    );
    for (id, name) in [(0, "Root"), (1, "Lobby")] {
        stream.extend(messages::frame(
            MessageType::ChannelState,
            &ChannelState {
                channel_id: Some(id),
                parent: (id > 0).then_some(0),
                name: Some(name.into()),
                max_users: None,
            },
        ));
    }
    stream.extend(user(5, "Bob", 0));
    stream.extend(user(6, "Cy", 1));
    stream.extend(user(3, "me", 0));
    stream.extend(messages::frame(
        MessageType::ServerSync,
        &ServerSync {
            session: Some(3),
            welcome_text: Some("hi".into()),
            ..Default::default()
        },
    ));
    core.handle_stream(&stream, now);
    core
}

#[test]
fn the_join_says_who_we_are_and_who_is_there() {
    let now = Instant::now();
    let mut core = ClientCore::new(config(None, false), server(), now);
    core.connected(now);
    let hello = sent(&mut core);
    assert_eq!(hello[0].0, MessageType::Version as u16);
    assert_eq!(hello[1].0, MessageType::Authenticate as u16);
    let auth = <messages::Authenticate as prost::Message>::decode(hello[1].1.as_slice()).unwrap();
    assert_eq!(auth.username.as_deref(), Some("me"));
    assert_eq!(auth.opus, Some(true));

    let mut core = joined(now, None, false);
    let got = events(&mut core);
    assert!(got.contains(&ClientEvent::UserJoined {
        session: 5,
        name: "Bob".into()
    }));
    assert!(
        !got.iter()
            .any(|e| matches!(e, ClientEvent::UserJoined { session: 6 | 3, .. }))
    );
    assert!(
        got.iter()
            .any(|e| matches!(e, ClientEvent::Synced { session: 3, .. }))
    );
    assert_eq!(core.current_channel().as_deref(), Some("Root"));
}

#[test]
fn a_channel_asked_for_is_joined_and_its_users_become_the_peers() {
    let now = Instant::now();
    let mut core = joined(now, Some("Lobby"), false);
    let moves: Vec<_> = sent(&mut core)
        .into_iter()
        .filter(|(t, _)| *t == MessageType::UserState as u16)
        .collect();
    assert_eq!(moves.len(), 1);
    events(&mut core);
    // The server confirms the move.
    core.handle_stream(&user(3, "me", 1), now);
    let got = events(&mut core);
    assert!(got.contains(&ClientEvent::UserLeft {
        session: 5,
        name: "Bob".into()
    }));
    assert!(got.contains(&ClientEvent::UserJoined {
        session: 6,
        name: "Cy".into()
    }));
    core.handle_stream(
        &messages::frame(
            MessageType::UserRemove,
            &UserRemove {
                session: Some(6),
                ..Default::default()
            },
        ),
        now,
    );
    assert!(events(&mut core).contains(&ClientEvent::UserLeft {
        session: 6,
        name: "Cy".into()
    }));
}

/// The UserStates the client sent: (session, channel, self_mute).
fn user_states(core: &mut ClientCore) -> Vec<(Option<u32>, Option<u32>, Option<bool>)> {
    sent(core)
        .into_iter()
        .filter(|(t, _)| *t == MessageType::UserState as u16)
        .map(|(_, body)| {
            let u = <UserState as prost::Message>::decode(body.as_slice()).unwrap();
            (u.session, u.channel_id, u.self_mute)
        })
        .collect()
}

#[test]
fn self_mute_is_told_once_per_change_seen_in_others_and_told_again_after_a_reconnect() {
    let now = Instant::now();
    let mut core = joined(now, None, false);
    sent(&mut core);
    core.set_self_mute(true, now);
    core.set_self_mute(true, now);
    assert_eq!(user_states(&mut core), [(Some(3), None, Some(true))]);
    // Push-to-talk pressed and let go within the server's message limit: held back, and the
    // last state told once the pace allows (unmuted then muted again: nothing to tell).
    core.set_self_mute(false, now + Duration::from_millis(100));
    core.set_self_mute(true, now + Duration::from_millis(200));
    core.set_self_mute(false, now + Duration::from_millis(300));
    assert_eq!(user_states(&mut core), []);
    let due = now + SELF_MUTE_EVERY;
    assert!(core.next_wake() <= due);
    core.wake(due);
    assert_eq!(user_states(&mut core), [(Some(3), None, Some(false))]);
    core.set_self_mute(true, due + Duration::from_millis(50));
    core.set_self_mute(false, due + Duration::from_millis(60));
    core.wake(due + SELF_MUTE_EVERY);
    assert_eq!(user_states(&mut core), []);
    core.set_self_mute(true, due + SELF_MUTE_EVERY);
    assert_eq!(user_states(&mut core), [(Some(3), None, Some(true))]);

    // Bob mutes himself; the members say so, and who we are.
    core.handle_stream(
        &messages::frame(
            MessageType::UserState,
            &UserState {
                session: Some(5),
                self_mute: Some(true),
                ..Default::default()
            },
        ),
        now,
    );
    let members = core.members();
    let bob = members.iter().find(|m| m.session == 5).unwrap();
    assert!(bob.self_mute && bob.channel == 0 && !bob.us);
    assert!(members.iter().any(|m| m.session == 3 && m.us));

    // A move is remembered: after a reconnect we go back there, still muted.
    core.join_channel(1);
    assert_eq!(user_states(&mut core), [(Some(3), Some(1), None)]);
    core.disconnected(now);
    core.connected(now);
    sent(&mut core);
    let mut again = Vec::new();
    for (id, name) in [(0, "Root"), (1, "Lobby")] {
        again.extend(messages::frame(
            MessageType::ChannelState,
            &ChannelState {
                channel_id: Some(id),
                parent: (id > 0).then_some(0),
                name: Some(name.into()),
                max_users: None,
            },
        ));
    }
    again.extend(user(3, "me", 0));
    again.extend(messages::frame(
        MessageType::ServerSync,
        &ServerSync {
            session: Some(3),
            ..Default::default()
        },
    ));
    core.handle_stream(&again, now);
    let told = user_states(&mut core);
    assert!(told.contains(&(Some(3), None, Some(true))), "{told:?}");
    assert!(told.contains(&(Some(3), Some(1), None)), "{told:?}");
}

fn opus_frame() -> Vec<u8> {
    let mut encoder =
        opus::Encoder::new(48_000, opus::Channels::Mono, opus::Application::Voip).unwrap();
    let pcm: Vec<i16> = (0..960)
        .map(|i| ((i as f32 * 0.05).sin() * 8000.0) as i16)
        .collect();
    encoder.encode_vec(&pcm, 400).unwrap()
}

#[test]
fn voice_by_udp_and_through_the_tunnel_reaches_each_speakers_receiver() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    let mut server_crypt = CryptState::new(&KEY, THEIRS, OURS);
    let frame = opus_frame();
    for i in 0..10u64 {
        let at = t0 + Duration::from_millis(20 * i);
        let packet = voice::server_opus(5, 2 * i, &frame, false);
        if i % 2 == 0 {
            core.datagram(&server_crypt.encrypt(&packet), server(), at);
        } else {
            core.handle_stream(&messages::tunnel(&packet), at);
        }
    }
    assert_eq!(core.stats.udp_received, 5);
    assert_eq!(core.stats.tunnel_received, 5);
    assert!(core.udp_working());
    let mut frames = Vec::new();
    for i in 0..20u32 {
        core.pull(
            t0 + Duration::from_millis(100 + 20 * u64::from(i)),
            &mut frames,
        );
    }
    assert!(frames.iter().all(|f| f.peer == PeerId::Mumble(5)));
    assert!(frames.len() >= 8, "{} frames", frames.len());
    let speakers = core.speakers();
    assert_eq!(speakers.len(), 1);
    assert_eq!(speakers[0].1, "Bob");
    assert_eq!(speakers[0].2.jitter.lost, 0);

    // Our voice goes by UDP now that UDP works, and decrypts at the server (after the UDP
    // ping of the join).
    core.send_voice(&frame, 960).unwrap();
    let mut server_rx = CryptState::new(&KEY, THEIRS, OURS);
    let plain: Vec<Vec<u8>> = std::iter::from_fn(|| core.next_transmit())
        .map(|t| server_rx.decrypt(&t.data).unwrap())
        .collect();
    assert_eq!(plain.len(), 2);
    assert_eq!(plain[0][0] >> 5, voice::TYPE_PING);
    assert_eq!(plain[1], voice::client_opus(0, &frame, false).unwrap());
    assert_eq!(core.stats.udp_sent, 1);
}

#[test]
fn tcp_only_sends_everything_through_the_tunnel() {
    let now = Instant::now();
    let mut core = joined(now, None, true);
    sent(&mut core);
    core.send_voice(&opus_frame(), 960).unwrap();
    assert!(core.next_transmit().is_none());
    let tunnelled = sent(&mut core);
    assert_eq!(tunnelled.len(), 1);
    assert_eq!(tunnelled[0].0, MessageType::UdpTunnel as u16);
    assert_eq!(tunnelled[0].1[0] >> 5, voice::TYPE_OPUS);
}

#[test]
fn datagrams_that_stop_decrypting_ask_for_fresh_nonces_and_the_answer_resyncs() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    sent(&mut core);
    let mut server_crypt = CryptState::new(&KEY, THEIRS, OURS);
    let ping = voice::ping(1);
    core.datagram(&server_crypt.encrypt(&ping), server(), t0);
    // The server's nonce runs far ahead (lost packets beyond the window).
    for _ in 0..300 {
        server_crypt.encrypt(&ping);
    }
    let late = t0 + Duration::from_secs(6);
    core.datagram(&server_crypt.encrypt(&ping), server(), late);
    let asked = sent(&mut core);
    assert!(
        asked
            .iter()
            .any(|(t, body)| *t == MessageType::CryptSetup as u16 && body.is_empty())
    );
    // Asked once, not for every bad datagram.
    core.datagram(&server_crypt.encrypt(&ping), server(), late);
    assert!(sent(&mut core).is_empty());
    // The server's answer: its nonce.
    core.handle_stream(
        &messages::frame(
            MessageType::CryptSetup,
            &CryptSetup {
                server_nonce: Some(server_crypt.encrypt_iv.to_vec()),
                ..Default::default()
            },
        ),
        late,
    );
    let before = core.stats.udp_received;
    core.datagram(&server_crypt.encrypt(&ping), server(), late);
    assert_eq!(core.stats.udp_received, before + 1);
}

#[test]
fn a_reject_is_said_in_words() {
    let now = Instant::now();
    let mut core = ClientCore::new(config(None, false), server(), now);
    core.connected(now);
    core.handle_stream(
        &messages::frame(
            MessageType::Reject,
            &messages::Reject {
                r#type: Some(messages::RejectType::WrongServerPw as i32),
                reason: Some("Wrong certificate or password".into()),
            },
        ),
        now,
    );
    match events(&mut core).as_slice() {
        [ClientEvent::Rejected(why)] => assert!(why.contains("wrong server password"), "{why}"),
        other => panic!("{other:?}"),
    }
}

fn remove(session: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserRemove,
        &UserRemove {
            session: Some(session),
            ..Default::default()
        },
    )
}

fn move_us(channel: u32) -> Vec<u8> {
    messages::frame(
        MessageType::UserState,
        &UserState {
            session: Some(3),
            channel_id: Some(channel),
            ..Default::default()
        },
    )
}

#[test]
fn a_move_storm_between_two_reports_is_one_comparison_and_the_news_is_budgeted() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    let mut crowd = Vec::new();
    for i in 0..500u32 {
        crowd.extend(user(100 + i, &format!("u{i}"), i % 2));
    }
    core.handle_stream(&crowd, t0);
    core.report_presence(t0);
    let first: Vec<ClientEvent> = std::iter::from_fn(|| core.poll_event()).collect();
    // Bob and 250 more in Root: 40 named, the rest counted.
    let named = first
        .iter()
        .filter(|e| matches!(e, ClientEvent::UserJoined { .. }))
        .count();
    assert_eq!(named, NEWS_PER_WINDOW as usize);
    assert!(first.contains(&ClientEvent::Unlisted {
        joined: 251 - u64::from(NEWS_PER_WINDOW),
        left: 0,
        messages: 0
    }));
    // 300 moves back and forth, ending where we were: nothing to say.
    let mut storm = Vec::new();
    for m in 0..300u32 {
        storm.extend(move_us(1 - m % 2));
    }
    let later = t0 + NEWS_WINDOW;
    core.handle_stream(&storm, later);
    core.report_presence(later);
    assert_eq!(core.poll_event(), None);
    // One more move, to Lobby: who is where, once, within the budget and counted beyond it.
    core.handle_stream(&move_us(1), later);
    core.report_presence(later);
    let moved: Vec<ClientEvent> = std::iter::from_fn(|| core.poll_event()).collect();
    assert_eq!(moved.len(), NEWS_PER_WINDOW as usize + 1, "{moved:?}");
    match moved.last() {
        Some(ClientEvent::Unlisted { joined, left, .. }) => {
            assert_eq!(joined + left + u64::from(NEWS_PER_WINDOW), 251 + 251);
        }
        other => panic!("{other:?}"),
    }
    // Within the window, further news is counted, not said.
    core.handle_stream(&move_us(0), later + Duration::from_secs(1));
    core.report_presence(later + Duration::from_secs(1));
    assert_eq!(core.poll_event(), None);
    core.report_presence(later + NEWS_WINDOW);
    assert!(matches!(
        core.poll_event(),
        Some(ClientEvent::Unlisted {
            joined: 251,
            left: 251,
            ..
        })
    ));
}

#[test]
fn removed_users_are_freed_and_speakers_are_capped() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    let frame = opus_frame();
    let mut frames = Vec::new();
    for i in 0..2000u32 {
        let session = 100 + i;
        let at = t0 + Duration::from_millis(u64::from(i));
        let mut bytes = user(session, &format!("guest{i}"), 0);
        bytes.extend(messages::tunnel(&voice::server_opus(
            session, 0, &frame, false,
        )));
        bytes.extend(remove(session));
        core.handle_stream(&bytes, at);
        core.pull(at, &mut frames);
        assert!(core.speakers.live().count() <= MAX_SPEAKERS);
    }
    // Bob, Cy and us are left; the speakers who left are listed up to a cap, the rest counted.
    assert_eq!(core.users.len(), 3);
    core.wake(t0 + Duration::from_secs(10));
    assert_eq!(core.speakers.live().count(), 0);
    let listed = core.speakers();
    assert_eq!(listed.len(), MAX_DEPARTED);
    assert!(listed.iter().all(|s| s.3));
    assert_eq!(core.speakers_unlisted(), 2000 - MAX_DEPARTED as u64);

    // Users beyond the cap are not kept.
    let mut crowd = Vec::new();
    for i in 0..MAX_USERS as u32 + 10 {
        crowd.extend(user(100_000 + i, "x", 1));
    }
    core.handle_stream(&crowd, t0);
    assert_eq!(core.users.len(), MAX_USERS);
    assert_eq!(core.stats.over_cap, 13);
}

#[test]
fn a_busy_speaker_keeps_its_receiver_and_a_quiet_one_makes_room() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    let frame = opus_frame();
    let mut crowd = Vec::new();
    for i in 0..=MAX_SPEAKERS as u32 {
        crowd.extend(user(100 + i, &format!("s{i}"), 0));
    }
    core.handle_stream(&crowd, t0);
    let speak = |core: &mut ClientCore, session: u32, at: Instant| {
        core.handle_stream(
            &messages::tunnel(&voice::server_opus(session, 0, &frame, false)),
            at,
        );
    };
    for i in 0..MAX_SPEAKERS as u32 {
        speak(&mut core, 100 + i, t0);
    }
    // One more, while everyone spoke just now: not heard.
    let newcomer = 100 + MAX_SPEAKERS as u32;
    speak(&mut core, newcomer, t0 + Duration::from_secs(1));
    assert_eq!(core.stats.over_cap, 1);
    // Later, the quietest lets go of its receiver (its reception is kept in the list).
    speak(&mut core, newcomer, t0 + Duration::from_secs(10));
    assert_eq!(core.stats.over_cap, 1);
    assert_eq!(core.speakers.live().count(), MAX_SPEAKERS);
    let listed = core.speakers();
    assert_eq!(listed.len(), MAX_SPEAKERS + 1);
    assert!(listed.iter().all(|s| !s.3), "all still in our channel");
}

#[test]
fn a_silent_server_counts_as_lost_and_repeated_syncs_and_removals_are_said_once() {
    let t0 = Instant::now();
    let mut core = joined(t0, None, false);
    events(&mut core);
    sent(&mut core);
    assert_eq!(core.server_silent(t0 + SERVER_SILENT / 2), None);
    core.handle_stream(&user(5, "Bob", 0), t0 + SERVER_SILENT / 2);
    assert_eq!(core.server_silent(t0 + SERVER_SILENT), None);
    let late = t0 + SERVER_SILENT / 2 + SERVER_SILENT;
    assert_eq!(core.server_silent(late), Some(SERVER_SILENT));

    let mut again = Vec::new();
    for _ in 0..1000 {
        again.extend(messages::frame(
            MessageType::ServerSync,
            &ServerSync {
                session: Some(3),
                ..Default::default()
            },
        ));
        again.extend(remove(3));
    }
    core.handle_stream(&again, late);
    let said = events(&mut core);
    assert_eq!(said.len(), 1, "{said:?}");
    assert!(matches!(said[0], ClientEvent::Removed(_)));
    assert!(
        sent(&mut core).is_empty(),
        "no answer to a repeated ServerSync"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// A hostile server's bytes (stream and datagrams, raw or properly encrypted): no panic,
    /// and whatever is framed comes out as framed.
    #[test]
    fn a_hostile_server_cannot_make_the_client_panic(
        ops in proptest::collection::vec((0u8..4, proptest::collection::vec(any::<u8>(), 0..80)), 0..40)
    ) {
        let t0 = Instant::now();
        let mut core = joined(t0, Some("Lobby"), false);
        let mut server_crypt = CryptState::new(&KEY, THEIRS, OURS);
        let mut frames = Vec::new();
        for (i, (op, bytes)) in ops.iter().enumerate() {
            let now = t0 + Duration::from_millis(20 * i as u64);
            match op {
                0 => core.handle_stream(bytes, now),
                1 => core.datagram(bytes, server(), now),
                2 => core.datagram(&server_crypt.encrypt(bytes), server(), now),
                _ => core.handle_stream(&messages::tunnel(bytes), now),
            }
            let _ = core.take_fatal();
            core.pull(now, &mut frames);
            core.wake(now);
            while core.poll_control().is_some() {}
            while core.next_transmit().is_some() {}
            while core.poll_event().is_some() {}
        }
        // The decoder of every frame message stays total.
        for kind in 0..30u16 {
            for (_, bytes) in &ops {
                let _ = Incoming::decode(kind, bytes);
            }
        }
    }
}
