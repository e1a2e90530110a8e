//! The desktop notification of a call that rings (a SIP call or a direct caller alike): the
//! freedesktop Notifications interface over the session bus, with *Answer* and *Decline*.
//!
//! Each notice runs on a thread of its own (the bus may be slow or absent: never the engine's
//! worker or the UI thread), every call on the bus under a timeout. It is closed when the
//! ringing ends (the [`RingNotice`] is dropped); the action the user picks comes back through
//! [`RingNotice::action`]. Without a session bus or a notification server it says so in one
//! log line and the rest of the ringing goes on.

use std::collections::HashMap;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;
use std::time::Duration;

use futures_util::StreamExt;
use tokio::sync::oneshot;

/// The longest any one call on the bus may take (connecting, posting, closing).
const BUS_TIMEOUT: Duration = Duration::from_secs(5);
/// The action keys the notice offers, as the server sends them back.
pub const ANSWER: &str = "answer";
pub const DECLINE: &str = "decline";

#[zbus::proxy(
    interface = "org.freedesktop.Notifications",
    default_service = "org.freedesktop.Notifications",
    default_path = "/org/freedesktop/Notifications"
)]
trait Notifications {
    #[allow(clippy::too_many_arguments)]
    fn notify(
        &self,
        app_name: &str,
        replaces_id: u32,
        app_icon: &str,
        summary: &str,
        body: &str,
        actions: &[&str],
        hints: HashMap<&str, zbus::Variant<'_>>,
        expire_timeout: i32,
    ) -> zbus::Result<u32>;

    fn close_notification(&self, id: u32) -> zbus::Result<()>;

    #[zbus(signal)]
    fn action_invoked(&self, id: u32, action_key: String) -> zbus::Result<()>;

    #[zbus(signal)]
    fn notification_closed(&self, id: u32, reason: u32) -> zbus::Result<()>;
}

/// What the user did with the notice.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoticeAction {
    Answer,
    Decline,
    /// Clicked the notice itself: bring the window up.
    Show,
}

/// A notice on the desktop while it lives; dropping it closes the notice (off the caller's
/// thread: the drop only signals).
pub struct RingNotice {
    /// The caller it names.
    about: String,
    stop: Option<oneshot::Sender<()>>,
    actions: Receiver<NoticeAction>,
    _thread: Option<JoinHandle<()>>,
}

impl RingNotice {
    /// Posts "`caller` is calling" with Answer and Decline.
    pub fn post(caller: &str) -> Self {
        let (stop, stopped) = oneshot::channel();
        let (tell, actions) = channel();
        let summary = format!("{caller} is calling");
        let thread = std::thread::Builder::new()
            .name("lipcall-notice".into())
            .spawn(move || run(&summary, stopped, &tell))
            .map_err(|e| tracing::warn!("no desktop notification: no thread for it: {e}"))
            .ok();
        Self {
            about: caller.to_owned(),
            stop: Some(stop),
            actions,
            _thread: thread,
        }
    }

    /// Whether it names `caller`.
    pub fn is_about(&self, caller: &str) -> bool {
        self.about == caller
    }

    /// The action the user picked since the last look, if any.
    pub fn action(&self) -> Option<NoticeAction> {
        self.actions.try_recv().ok()
    }
}

impl Drop for RingNotice {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

fn run(summary: &str, stopped: oneshot::Receiver<()>, tell: &Sender<NoticeAction>) {
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            tracing::warn!("no desktop notification: {e}");
            return;
        }
    };
    if let Err(e) = runtime.block_on(notice(summary, stopped, tell)) {
        tracing::warn!("no desktop notification of the call: {e}");
    }
}

async fn within<T>(what: &str, f: impl Future<Output = zbus::Result<T>>) -> Result<T, String> {
    match tokio::time::timeout(BUS_TIMEOUT, f).await {
        Ok(Ok(t)) => Ok(t),
        Ok(Err(e)) => Err(format!("{what}: {e}")),
        Err(_) => Err(format!("{what}: no answer in {} s", BUS_TIMEOUT.as_secs())),
    }
}

async fn notice(
    summary: &str,
    mut stopped: oneshot::Receiver<()>,
    tell: &Sender<NoticeAction>,
) -> Result<(), String> {
    let bus = within("the session bus", zbus::Connection::session()).await?;
    let proxy = within("the notification server", NotificationsProxy::new(&bus)).await?;
    // Listening before posting, so that no action comes before we hear.
    let mut invoked = within("its actions", proxy.receive_action_invoked()).await?;
    let mut closed = within("its closing", proxy.receive_notification_closed()).await?;
    let actions: &[&str] = &["default", "Show", ANSWER, "Answer", DECLINE, "Decline"];
    let hints = HashMap::from([
        ("urgency", zbus::Variant::from(2u8)),
        ("category", zbus::Variant::from("call.incoming")),
        ("resident", zbus::Variant::from(true)),
    ]);
    let body = "Answer or decline it here or in lipcall";
    let post = proxy.notify("lipcall", 0, "call-start", summary, body, actions, hints, 0);
    let id = within("posting it", post).await?;
    tracing::info!("desktop notification {id}: {summary}");
    loop {
        tokio::select! {
            _ = &mut stopped => break,
            Some(signal) = invoked.next() => {
                let Ok(args) = signal.args() else { continue };
                if *args.id() != id {
                    continue;
                }
                let action = match args.action_key().as_str() {
                    ANSWER => NoticeAction::Answer,
                    DECLINE => NoticeAction::Decline,
                    _ => NoticeAction::Show,
                };
                if tell.send(action).is_err() {
                    break;
                }
            }
            Some(signal) = closed.next() => {
                // Dismissed: the call still rings in the window.
                if signal.args().is_ok_and(|a| *a.id() == id) {
                    return Ok(());
                }
            }
        }
    }
    within("closing it", proxy.close_notification(id)).await
}
