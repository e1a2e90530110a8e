//! Errors of the audio device layer. Each renders as one line the app can show as it is.

#[derive(Debug, thiserror::Error)]
pub enum AudioError {
    #[error("no output device ({reason}): playing nothing")]
    NoOutput { reason: String },
    #[error("no input device ({reason}): receive-only")]
    NoInput { reason: String },
    #[error("audio device `{id}` not found")]
    DeviceNotFound { id: String },
    #[error("cannot list audio devices: {0}")]
    Host(String),
    #[error("unsupported sample format {0} (the device offers nothing we can convert)")]
    UnsupportedFormat(String),
    #[error("resampler: {0}")]
    Resampler(String),
    #[error("too many peers (at most {max})")]
    TooManyPeers { max: usize },
    #[error("the mixer thread has stopped")]
    MixerStopped,
}
