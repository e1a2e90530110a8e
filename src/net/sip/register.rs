//! Registration with a SIP registrar (RFC 3261 section 10): the account, digest answers to
//! its challenges (401 and 407, MD5 and SHA-256, by ezk-sip-auth) with a bound on how often,
//! a REGISTER that cannot hang (a registrar that does not answer is an error within
//! [`REGISTER_TIMEOUT`]), and the refresh that keeps the binding until the call ends.

use std::time::Duration;

use bytesstr::BytesStr;
use ezk_sip_auth::{
    ClientAuthenticator, DigestAuthenticator, DigestCredentials, DigestError, DigestUser,
    RequestParts, ResponseParts,
};
use ezk_sip_core::Endpoint;
use ezk_sip_core::transaction::TsxResponse;
use ezk_sip_core::transport::TargetTransportInfo;
use ezk_sip_types::header::typed::{Contact, Expires};
use ezk_sip_types::uri::SipUri;
use ezk_sip_types::{Headers, StatusCode};
use ezk_sip_ua::register::Registration;
use tokio::select;

use super::error::SipError;

/// How long a registrar may take to answer a REGISTER.
pub const REGISTER_TIMEOUT: Duration = Duration::from_secs(5);
/// The binding lifetime we ask for; ezk refreshes 10 s before it runs out.
pub const REGISTER_EXPIRY: Duration = Duration::from_secs(300);
/// Challenges answered for one request before the credentials count as wrong.
const MAX_CHALLENGES: u32 = 2;

/// A SIP account: who we are and how we prove it.
#[derive(Clone, PartialEq, Eq)]
pub struct Account {
    pub user: String,
    /// The account's domain (`HOST[:PORT]`), also the registrar unless one is given.
    pub domain: String,
    pub password: String,
    pub registrar: Option<String>,
}

impl std::fmt::Debug for Account {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The password never reaches a log.
        f.debug_struct("Account")
            .field("user", &self.user)
            .field("domain", &self.domain)
            .field("registrar", &self.registrar)
            .finish_non_exhaustive()
    }
}

impl Account {
    /// `sip:USER@DOMAIN` (or `USER@DOMAIN`) with its password.
    pub fn parse(uri: &str, password: &str) -> Result<Self, SipError> {
        let bare = uri.trim().trim_start_matches("sip:");
        let (user, domain) = bare
            .split_once('@')
            .filter(|(u, d)| !u.is_empty() && !d.is_empty())
            .ok_or_else(|| SipError::BadUri(uri.to_owned()))?;
        Ok(Self {
            user: user.to_owned(),
            domain: domain.to_owned(),
            password: password.to_owned(),
            registrar: None,
        })
    }

    pub fn registrar(&self) -> &str {
        self.registrar.as_deref().unwrap_or(&self.domain)
    }
}

/// Answers challenges, but only [`MAX_CHALLENGES`] times: a registrar that keeps challenging
/// with fresh nonces has refused the password.
pub struct Limited {
    digest: DigestAuthenticator,
    rejections: u32,
}

impl Limited {
    pub fn new(account: Option<&Account>) -> Self {
        let mut credentials = DigestCredentials::new();
        if let Some(a) = account {
            credentials.set_default(DigestUser::new(a.user.clone(), a.password.as_bytes()));
        }
        Self {
            digest: DigestAuthenticator::new(credentials),
            rejections: 0,
        }
    }
}

impl ClientAuthenticator for Limited {
    type Error = DigestError;

    fn authorize_request(&mut self, request: &mut Headers) {
        self.digest.authorize_request(request);
    }

    fn handle_rejection(
        &mut self,
        rejected_request: RequestParts<'_>,
        reject_response: ResponseParts<'_>,
    ) -> Result<(), Self::Error> {
        self.rejections += 1;
        if self.rejections > MAX_CHALLENGES {
            return Err(DigestError::FailedToAuthenticate(Vec::new()));
        }
        self.digest
            .handle_rejection(rejected_request, reject_response)
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

/// Sends REGISTER (or, with `remove`, its removal) until the registrar accepts or refuses.
pub async fn register(
    endpoint: &Endpoint,
    registration: &mut Registration,
    auth: &mut Limited,
    target: &mut TargetTransportInfo,
    registrar: &str,
    remove: bool,
) -> Result<(), SipError> {
    auth.rejections = 0;
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
        match code.into_u16() {
            200..=299 => {
                if !remove {
                    registration.receive_success_response(with_granted_expiry(response));
                }
                return Ok(());
            }
            401 | 407 => {
                let request = transaction.request();
                auth.handle_rejection(
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
                .map_err(|_| SipError::BadCredentials(registrar.to_owned()))?;
            }
            423 if !remove && registration.receive_error_response(response) => {}
            other => {
                return Err(SipError::RegisterRefused {
                    registrar: registrar.to_owned(),
                    code: other,
                    reason,
                });
            }
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

/// Keeps the binding fresh until told to stop, then removes it.
pub async fn keep_registered(
    endpoint: Endpoint,
    mut registration: Registration,
    mut auth: Limited,
    mut target: TargetTransportInfo,
    registrar: String,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) {
    loop {
        select! {
            _ = &mut stop => break,
            () = registration.wait_for_expiry() => {
                if let Err(e) = register(&endpoint, &mut registration, &mut auth, &mut target, &registrar, false).await {
                    tracing::warn!("refreshing the registration: {e}");
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
    }

    #[test]
    fn uris_without_scheme_get_one() {
        assert!(uri("bob@127.0.0.1:5060").is_ok());
        assert!(uri("sip:bob@127.0.0.1").is_ok());
        assert!(uri("sip:").is_err());
    }
}
