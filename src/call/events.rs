//! A link's news waiting for its next poll, bounded: a peer that makes a link say things
//! faster than its owner polls (a flood of provisional answers or re-INVITEs, an owner that
//! stopped polling) costs at most [`LinkEvents::new`]'s cap. Past it the oldest line that only
//! informs goes, counted; the call's joining and its end are kept.

use std::collections::VecDeque;

use crate::call::link::LinkEvent;

#[derive(Debug)]
pub struct LinkEvents {
    queue: VecDeque<LinkEvent>,
    cap: usize,
    dropped: u64,
}

/// What a poll must not miss: the call joined, or ended.
fn essential(event: &LinkEvent) -> bool {
    event.ends_call() || matches!(event, LinkEvent::Joined { .. })
}

impl LinkEvents {
    /// Holds `cap` events at most (at least one).
    pub fn new(cap: usize) -> Self {
        Self {
            queue: VecDeque::new(),
            cap: cap.max(1),
            dropped: 0,
        }
    }

    pub fn push(&mut self, event: LinkEvent) {
        if self.queue.len() >= self.cap {
            match self.queue.iter().position(|e| !essential(e)) {
                Some(oldest) => drop(self.queue.remove(oldest)),
                None if !essential(&event) => {
                    self.count_drop();
                    return;
                }
                None => drop(self.queue.pop_front()),
            }
            self.count_drop();
        }
        self.queue.push_back(event);
    }

    fn count_drop(&mut self) {
        if self.dropped == 0 {
            tracing::warn!("the call says more than is read: older news dropped");
        }
        self.dropped += 1;
    }

    /// Everything since the last take, oldest first.
    pub fn take(&mut self) -> Vec<LinkEvent> {
        self.queue.drain(..).collect()
    }

    /// Events dropped for room since the link started.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn progress(n: usize) -> LinkEvent {
        LinkEvent::Progress(format!("ringing {n}"))
    }

    #[test]
    fn a_flood_keeps_the_cap_and_the_newest_lines_and_never_the_end_of_the_call() {
        let mut events = LinkEvents::new(8);
        events.push(LinkEvent::Joined {
            place: "a call".into(),
            id: "1".into(),
        });
        for n in 0..10_000 {
            events.push(progress(n));
        }
        events.push(LinkEvent::Ended {
            reason: "hung up".into(),
        });
        assert_eq!(events.dropped(), 10_002 - 8);
        let kept = events.take();
        assert_eq!(kept.len(), 8);
        assert!(matches!(kept[0], LinkEvent::Joined { .. }));
        assert_eq!(kept[1], progress(9_994));
        assert_eq!(kept[6], progress(9_999));
        assert!(kept[7].ends_call());
        // Taken: room again, nothing more dropped.
        assert!(events.take().is_empty());
        events.push(progress(0));
        assert_eq!((events.take().len(), events.dropped()), (1, 10_002 - 8));
    }

    #[test]
    fn when_only_essential_news_is_queued_a_line_that_only_informs_is_the_one_dropped() {
        let mut events = LinkEvents::new(2);
        let failed = |why: &str| LinkEvent::Failed(why.into());
        events.push(failed("one"));
        events.push(failed("two"));
        events.push(progress(1));
        assert_eq!(events.dropped(), 1);
        events.push(failed("three"));
        assert_eq!(events.take(), [failed("two"), failed("three")]);
        assert_eq!(events.dropped(), 2);
    }
}
