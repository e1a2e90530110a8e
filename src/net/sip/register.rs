//! Registration with a SIP registrar (RFC 3261 section 10): the account, digest answers to
//! its challenges (401 and 407, MD5 and SHA-256, by ezk-sip-auth) with a bound on how often,
//! a REGISTER that cannot hang (a registrar that does not answer is an error within
//! [`REGISTER_TIMEOUT`]), 423 Interval Too Brief honoured once, and the refresh that keeps the
//! binding until the call ends (a failed one tried again after a growing pause).
//!
//! The password is answered for only in the account's home: the realm the registrar's own
//! challenge named, to challenges from the account's servers ([`Home`]). A callee that
//! challenges our INVITE itself gets nothing: a digest over its nonce would let it try a word
//! list against the password offline.

use std::net::SocketAddr;
use std::time::Duration;

use bytesstr::BytesStr;
use ezk_sip_auth::{
    ClientAuthenticator, DigestAuthenticator, DigestCredentials, DigestError, DigestUser,
    RequestParts, ResponseParts,
};
use ezk_sip_core::Endpoint;
use ezk_sip_core::transaction::TsxResponse;
use ezk_sip_core::transport::{OutgoingRequest, TargetTransportInfo};
use ezk_sip_types::header::typed::{AuthChallenge, CSeq, Contact, Expires, MinExpires};
use ezk_sip_types::host::{Host, HostPort};
use ezk_sip_types::uri::SipUri;
use ezk_sip_types::{Headers, Method, Name, StatusCode};
use ezk_sip_ua::register::Registration;
use tokio::select;
use zeroize::Zeroize;

use super::error::SipError;
use super::transport::{SipTransport, with_port};
use crate::net::backoff::Backoff;

/// How long a registrar may take to answer a REGISTER.
pub const REGISTER_TIMEOUT: Duration = Duration::from_secs(5);
/// The binding lifetime we ask for; ezk refreshes 10 s before it runs out.
pub const REGISTER_EXPIRY: Duration = Duration::from_secs(300);
/// The longest binding a registrar may demand with 423 (Min-Expires): an hour, RFC 3261's
/// default registration.
pub const MAX_MIN_EXPIRES: u32 = 3600;
/// A refresh that failed is tried again after this, then after twice as long each time, up
/// to [`REFRESH_RETRY_MAX`].
const REFRESH_RETRY: Duration = Duration::from_secs(10);
const REFRESH_RETRY_MAX: Duration = Duration::from_secs(300);
/// How often a registered account on UDP sends OPTIONS to its registrar while it idles: home
/// routers forget UDP mappings after 30 to 120 s.
pub const UDP_KEEPALIVE: Duration = Duration::from_secs(25);
/// Challenges answered for one request before the credentials count as wrong.
const MAX_CHALLENGES: u32 = 2;
/// Where a SIP URI without a port is served.
const SIP_PORT: u16 = 5060;

/// A SIP account: who we are and how we prove it. The password is overwritten when dropped.
#[derive(Clone, PartialEq, Eq)]
pub struct Account {
    pub user: String,
    /// The account's domain (`HOST[:PORT]`), also the registrar unless one is given.
    pub domain: String,
    pub password: String,
    pub registrar: Option<String>,
    /// How its registrar is reached (`sips:` or `;transport=` of the account's URI); calls
    /// from the account go the same way.
    pub transport: SipTransport,
}

impl std::fmt::Debug for Account {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The password never reaches a log.
        f.debug_struct("Account")
            .field("user", &self.user)
            .field("domain", &self.domain)
            .field("registrar", &self.registrar)
            .field("transport", &self.transport)
            .finish_non_exhaustive()
    }
}

impl Drop for Account {
    fn drop(&mut self) {
        self.password.zeroize();
    }
}

impl Account {
    /// `sip:USER@DOMAIN[;transport=tcp|tls]`, `sips:USER@DOMAIN` (or `USER@DOMAIN`) with its
    /// password.
    pub fn parse(uri: &str, password: &str) -> Result<Self, SipError> {
        let transport = SipTransport::of_uri(uri)?;
        let trimmed = uri.trim();
        let bare = trimmed
            .strip_prefix("sips:")
            .or_else(|| trimmed.strip_prefix("sip:"))
            .unwrap_or(trimmed);
        let bare = bare.split([';', '?']).next().unwrap_or(bare);
        let (user, domain) = bare
            .split_once('@')
            .filter(|(u, d)| !u.is_empty() && !d.is_empty())
            .ok_or_else(|| SipError::BadUri(uri.to_owned()))?;
        Ok(Self {
            user: user.to_owned(),
            domain: domain.to_owned(),
            password: password.to_owned(),
            registrar: None,
            transport,
        })
    }

    /// The registrar's `HOST[:PORT]`.
    pub fn registrar(&self) -> &str {
        self.registrar.as_deref().unwrap_or(&self.domain)
    }

    /// The registrar's `HOST:PORT` (the transport's port where none is given).
    pub fn registrar_with_port(&self) -> String {
        with_port(self.registrar(), self.transport)
    }

    /// The registrar as ezk reaches it: `sip:HOST:PORT` with the transport's parameter.
    pub fn registrar_uri(&self) -> String {
        format!(
            "sip:{}{}",
            self.registrar_with_port(),
            self.transport.param()
        )
    }
}

/// Where the account's password may be answered for: the realm the registrar's own challenge
/// named, challenges from the address the registrar answered from, or from where a request to
/// the account's domain or registrar host went.
#[derive(Debug, Clone, Default)]
pub struct Home {
    realm: Option<String>,
    registrar: Option<SocketAddr>,
    hosts: Vec<HostPort>,
}

impl Home {
    fn of(account: &Account) -> Self {
        let hosts = [
            with_port(&account.domain, account.transport),
            account.registrar_with_port(),
        ]
        .into_iter()
        .filter_map(|host| uri(&host).ok())
        .map(|uri| uri.host_port)
        .collect();
        Self {
            hosts,
            ..Self::default()
        }
    }

    /// Whether `request` went to the account's servers and the challenge came back from there.
    fn served(&self, request: &OutgoingRequest, from: SocketAddr) -> bool {
        let sent_to = request.parts.destination;
        let to_home = Some(sent_to) == self.registrar
            || self
                .hosts
                .iter()
                .any(|host| same_server(host, &request.msg.line.uri.host_port));
        to_home && (from == sent_to || Some(from) == self.registrar)
    }
}

fn same_server(a: &HostPort, b: &HostPort) -> bool {
    let hosts = match (&a.host, &b.host) {
        (Host::Name(x), Host::Name(y)) => x.eq_ignore_ascii_case(y),
        (x, y) => x == y,
    };
    hosts && a.port.unwrap_or(SIP_PORT) == b.port.unwrap_or(SIP_PORT)
}

/// The realms a 401 or 407 challenges with a digest.
fn digest_realms(headers: &Headers) -> Vec<String> {
    [Name::WWW_AUTHENTICATE, Name::PROXY_AUTHENTICATE]
        .into_iter()
        .filter_map(|name| headers.try_get::<Vec<AuthChallenge>>(name))
        .flat_map(|challenges| challenges.unwrap_or_default())
        .filter_map(|challenge| match challenge {
            AuthChallenge::Digest(digest) => Some(digest.realm.to_string()),
            AuthChallenge::Other(_) => None,
        })
        .collect()
}

/// Why a challenge got no answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// Not our account's: not from its servers, or in another realm.
    Foreign { realm: String, from: SocketAddr },
    /// Challenged again and again (fresh nonces): the credentials are wrong.
    Exhausted,
}

impl Refusal {
    /// The error a refused challenge (a `code` response) is; `wrong_credentials` where the
    /// challenges did not stop.
    pub fn error(self, code: u16, wrong_credentials: SipError) -> SipError {
        match self {
            Self::Foreign { realm, from } => SipError::ForeignChallenge {
                asker: from.to_string(),
                code,
                realm,
            },
            Self::Exhausted => wrong_credentials,
        }
    }
}

/// Answers the account's challenges, only in its [`Home`] and only [`MAX_CHALLENGES`] times
/// per request: a registrar that keeps challenging with fresh nonces has refused the password.
pub struct Limited {
    digest: DigestAuthenticator,
    /// The account's credentials, given to `digest` for the home realm once it is known.
    user: Option<DigestUser>,
    home: Home,
    /// The registrar's first challenge names the home realm.
    learning: bool,
    rejections: u32,
}

impl Limited {
    /// For the account's registration: the realm of the registrar's first challenge becomes
    /// the home realm.
    pub fn for_registration(account: &Account) -> Self {
        let mut limited = Self::for_calls(Some(account), Home::of(account));
        limited.learning = true;
        limited
    }

    /// For a call: answers in `home`'s realm only, and only challenges from its servers.
    pub fn for_calls(account: Option<&Account>, home: Home) -> Self {
        let mut limited = Self {
            digest: DigestAuthenticator::new(DigestCredentials::new()),
            user: account.map(|a| DigestUser::new(a.user.clone(), a.password.as_bytes())),
            home,
            learning: false,
            rejections: 0,
        };
        if let Some(realm) = limited.home.realm.clone() {
            limited.trust_realm(realm);
        }
        limited
    }

    /// Where this account's password went: for the calls that follow a registration.
    pub fn home(&self) -> &Home {
        &self.home
    }

    fn trust_realm(&mut self, realm: String) {
        if let Some(user) = self.user.clone() {
            self.digest.credentials.add_for_realm(realm.clone(), user);
        }
        self.home.realm = Some(realm);
    }

    /// Adds the digest answers we have to a request.
    pub fn authorize_request(&mut self, request: &mut Headers) {
        self.digest.authorize_request(request);
    }

    /// A new request: its challenges are counted afresh.
    pub fn new_request(&mut self) {
        self.rejections = 0;
    }

    /// Answers `response`'s challenge to `request` (the next request carries the digest), or
    /// says why not.
    pub fn answer(
        &mut self,
        request: &OutgoingRequest,
        response: &TsxResponse,
    ) -> Result<(), Refusal> {
        self.rejections += 1;
        if self.rejections > MAX_CHALLENGES {
            return Err(Refusal::Exhausted);
        }
        let from = response.tp_info.source;
        let realms = digest_realms(&response.headers);
        let served = self.home.served(request, from);
        if served && self.learning && self.home.realm.is_none() {
            self.home.registrar = Some(from);
            if let Some(first) = realms.first() {
                self.trust_realm(first.clone());
            }
        }
        let foreign = realms
            .iter()
            .find(|realm| self.home.realm.as_ref() != Some(*realm));
        if !served || foreign.is_some() {
            let realm = foreign.or(realms.first()).cloned().unwrap_or_default();
            return Err(Refusal::Foreign { realm, from });
        }
        self.digest
            .handle_rejection(
                RequestParts {
                    line: &request.msg.line,
                    headers: &request.msg.headers,
                    body: &request.msg.body,
                },
                ResponseParts {
                    line: &response.line,
                    headers: &response.headers,
                    body: &response.body,
                },
            )
            .map_err(|_: DigestError| Refusal::Exhausted)
    }
}

pub fn uri(text: &str) -> Result<SipUri, SipError> {
    let full = if text.starts_with("sip:") || text.starts_with("sips:") {
        text.to_owned()
    } else {
        format!("sip:{text}")
    };
    full.parse::<SipUri>()
        .map_err(|_| SipError::BadUri(text.to_owned()))
}

pub fn reason_of(code: StatusCode, reason: Option<&BytesStr>) -> String {
    reason
        .map(|r| r.to_string())
        .or_else(|| code.text().map(str::to_owned))
        .unwrap_or_default()
}

/// Sends REGISTER (or, with `remove`, its removal) until the registrar accepts or refuses:
/// at most [`MAX_CHALLENGES`] challenges and one 423 answered, so at most four REGISTERs.
pub async fn register(
    endpoint: &Endpoint,
    registration: &mut Registration,
    auth: &mut Limited,
    target: &mut TargetTransportInfo,
    registrar: &str,
    remove: bool,
) -> Result<(), SipError> {
    auth.new_request();
    let mut lengthened = false;
    loop {
        let mut request = registration.create_register(remove);
        request.headers.insert_named(endpoint.allowed());
        auth.authorize_request(&mut request.headers);
        let exchange = async {
            let mut transaction = endpoint.send_request(request, target).await?;
            let response = transaction.receive_final().await?;
            Ok::<_, ezk_sip_core::Error>((transaction, response))
        };
        let (transaction, response) = match tokio::time::timeout(REGISTER_TIMEOUT, exchange).await {
            Err(_) | Ok(Err(ezk_sip_core::Error::RequestTimedOut)) => {
                return Err(SipError::RegistrarSilent(
                    registrar.to_owned(),
                    REGISTER_TIMEOUT.as_secs(),
                ));
            }
            Ok(Err(e)) => return Err(SipError::Protocol(format!("REGISTER: {e}"))),
            Ok(Ok(exchanged)) => exchanged,
        };
        let code = response.line.code;
        let reason = reason_of(code, response.line.reason.as_ref());
        let refused = || SipError::RegisterRefused {
            registrar: registrar.to_owned(),
            code: code.into_u16(),
            reason: reason.clone(),
        };
        match code.into_u16() {
            200..=299 => {
                if !remove {
                    registration.receive_success_response(with_granted_expiry(response));
                }
                return Ok(());
            }
            401 | 407 => auth
                .answer(transaction.request(), &response)
                .map_err(|refusal| {
                    refusal.error(
                        code.into_u16(),
                        SipError::BadCredentials(registrar.to_owned()),
                    )
                })?,
            423 if !remove => {
                let Ok(MinExpires(min_expires)) = response.headers.get_named::<MinExpires>() else {
                    return Err(refused());
                };
                if std::mem::replace(&mut lengthened, true) {
                    return Err(SipError::IntervalLoop {
                        registrar: registrar.to_owned(),
                        min_expires,
                    });
                }
                if min_expires > MAX_MIN_EXPIRES {
                    return Err(SipError::IntervalTooLong {
                        registrar: registrar.to_owned(),
                        min_expires,
                        max: MAX_MIN_EXPIRES,
                    });
                }
                if !registration.receive_error_response(response) {
                    return Err(refused());
                }
            }
            _ => return Err(refused()),
        }
    }
}

/// A 200 to REGISTER with the binding's lifetime as an Expires header, which is where ezk
/// reads it: registrars that shorten it (kamailio's `max_expires`) often say so only in the
/// Contact's `expires` parameter, and a refresh timed by what we asked for would come too late.
fn with_granted_expiry(mut response: TsxResponse) -> TsxResponse {
    if response.headers.get_named::<Expires>().is_ok() {
        return response;
    }
    let granted = response
        .headers
        .get_named::<Vec<Contact>>()
        .ok()
        .and_then(|contacts| {
            contacts
                .iter()
                .filter_map(|c| c.params.get_val("expires"))
                .filter_map(|v| v.parse::<u32>().ok())
                .min()
        });
    if let Some(seconds) = granted {
        response.headers.insert_named(&Expires(seconds));
    }
    response
}

/// Sends OPTIONS to the registrar from the registration's socket: a NAT between us keeps the
/// mapping that incoming calls arrive through. Its answer, whatever it is, only shows the
/// path is open.
async fn ping(
    endpoint: &Endpoint,
    registration: &mut Registration,
    target: &mut TargetTransportInfo,
) {
    let mut request = registration.create_register(false);
    request.line.method = Method::OPTIONS;
    let cseq = request.headers.get_named::<CSeq>().map_or(1, |c| c.cseq);
    for name in [Name::CSEQ, Name::EXPIRES, Name::CONTACT] {
        request.headers.remove(&name);
    }
    request
        .headers
        .insert_named(&CSeq::new(cseq, Method::OPTIONS));
    let exchange = async {
        let mut transaction = endpoint.send_request(request, target).await?;
        transaction.receive_final().await
    };
    match tokio::time::timeout(REGISTER_TIMEOUT, exchange).await {
        Ok(Ok(response)) => tracing::debug!("keepalive: {}", response.line.code.into_u16()),
        Ok(Err(e)) => tracing::debug!("keepalive: {e}"),
        Err(_) => tracing::debug!("keepalive: no answer"),
    }
}

/// Keeps the binding fresh until told to stop, then removes it. A refresh that fails is tried
/// again after [`REFRESH_RETRY`], doubling up to [`REFRESH_RETRY_MAX`], until one succeeds.
pub async fn keep_registered(
    endpoint: Endpoint,
    mut registration: Registration,
    mut auth: Limited,
    mut target: TargetTransportInfo,
    registrar: String,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) {
    let mut retry = Backoff::new(REFRESH_RETRY, REFRESH_RETRY_MAX);
    let mut retry_in: Option<Duration> = None;
    // TCP and TLS connections are pinged with CRLF by ezk itself (RFC 5626 4.4.1).
    let udp = target.transport.as_ref().is_some_and(|(t, _)| t.is_udp());
    let mut keepalive =
        tokio::time::interval_at(tokio::time::Instant::now() + UDP_KEEPALIVE, UDP_KEEPALIVE);
    keepalive.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        select! {
            _ = &mut stop => break,
            _ = keepalive.tick(), if udp => {
                ping(&endpoint, &mut registration, &mut target).await;
            }
            () = async {
                match retry_in {
                    Some(wait) => tokio::time::sleep(wait).await,
                    None => registration.wait_for_expiry().await,
                }
            } => {
                match register(&endpoint, &mut registration, &mut auth, &mut target, &registrar, false).await {
                    Ok(()) => {
                        retry.reset();
                        retry_in = None;
                    }
                    Err(e) => {
                        let wait = retry.next_wait();
                        tracing::warn!(
                            "refreshing the registration: {e} (trying again in {} s)",
                            wait.as_secs()
                        );
                        retry_in = Some(wait);
                    }
                }
            }
        }
    }
    if let Err(e) = register(
        &endpoint,
        &mut registration,
        &mut auth,
        &mut target,
        &registrar,
        true,
    )
    .await
    {
        tracing::debug!("removing the registration: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accounts_parse_and_never_print_their_password() {
        let a = Account::parse("sip:alice@127.0.0.1:5070", "s3cret").unwrap();
        assert_eq!(
            (a.user.as_str(), a.registrar()),
            ("alice", "127.0.0.1:5070")
        );
        assert!(!format!("{a:?}").contains("s3cret"));
        assert!(Account::parse("sip:nobody", "x").is_err());
        assert!(Account::parse("@host", "x").is_err());
        let tls = Account::parse("sips:alice@pbx.example", "pw").unwrap();
        assert_eq!(
            (tls.domain.as_str(), tls.registrar_uri()),
            (
                "pbx.example",
                "sip:pbx.example:5061;transport=tls".to_owned()
            )
        );
        let tcp = Account::parse("sip:alice@10.0.0.1:5070;transport=tcp", "pw").unwrap();
        assert_eq!(tcp.registrar_uri(), "sip:10.0.0.1:5070;transport=tcp");
    }

    #[test]
    fn the_accounts_servers_are_its_domain_and_registrar_on_sips_default_port() {
        let mut a = Account::parse("sip:alice@PBX.example", "pw").unwrap();
        a.registrar = Some("127.0.0.1:5070".into());
        let home = Home::of(&a);
        let host = |text: &str| uri(text).unwrap().host_port;
        for ours in ["pbx.example", "pbx.example:5060", "127.0.0.1:5070"] {
            assert!(
                home.hosts.iter().any(|h| same_server(h, &host(ours))),
                "{ours}"
            );
        }
        for other in [
            "pbx.example:5070",
            "127.0.0.1",
            "127.0.0.2:5070",
            "evil.example",
        ] {
            assert!(
                !home.hosts.iter().any(|h| same_server(h, &host(other))),
                "{other}"
            );
        }
    }

    #[test]
    fn the_realms_of_digest_challenges_in_either_header() {
        let mut headers = Headers::new();
        headers.insert(
            Name::WWW_AUTHENTICATE,
            "Digest realm=\"home\", nonce=\"n\", algorithm=MD5",
        );
        headers.insert(
            Name::PROXY_AUTHENTICATE,
            "Digest realm=\"proxy\", nonce=\"m\"",
        );
        assert_eq!(digest_realms(&headers), ["home", "proxy"]);
        assert!(digest_realms(&Headers::new()).is_empty());
    }

    #[test]
    fn a_foreign_challenge_is_an_error_that_names_its_realm_and_asker() {
        let refusal = Refusal::Foreign {
            realm: "evil".into(),
            from: "127.0.0.1:5099".parse().unwrap(),
        };
        let e = refusal
            .error(401, SipError::CallAuth("x".into()))
            .to_string();
        assert!(
            e.contains("127.0.0.1:5099 asked for our password in realm \"evil\""),
            "{e}"
        );
        let wrong = SipError::BadCredentials("r".into());
        assert_eq!(Refusal::Exhausted.error(401, wrong.clone()), wrong);
    }

    #[test]
    fn uris_without_scheme_get_one() {
        assert!(uri("bob@127.0.0.1:5060").is_ok());
        assert!(uri("sip:bob@127.0.0.1").is_ok());
        assert!(uri("sip:").is_err());
    }
}
