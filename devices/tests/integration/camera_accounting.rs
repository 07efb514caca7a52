//! Trigger accounting against a model camera: random triggers, deliveries, drops, duplicates,
//! spontaneous frames and waits. Every frame must be matched to the trigger that really
//! caused it, and every fault must be reported.

use std::collections::{HashMap, VecDeque};

use proptest::prelude::*;
use stagehand_devices::cameras::accounting::{FrameVerdict, TriggerAccounting, frame_timeout_s};
use stagehand_devices::{DeviceError, DeviceErrorKind};

/// What happens next on the model rig.
#[derive(Debug, Clone)]
enum Ev {
    /// A trigger fires; the camera will produce one frame for it.
    Fire,
    /// The oldest produced frame reaches the host.
    Deliver,
    /// The oldest produced frame is lost on the way (its sequence number is used up).
    Drop,
    /// The last delivered frame is delivered again.
    Duplicate,
    /// The camera produces a frame nobody triggered.
    Spontaneous,
    /// Time passes (seconds).
    Wait(f64),
}

fn events(allow_spontaneous: bool) -> impl Strategy<Value = Vec<Ev>> {
    let spont = if allow_spontaneous { 1 } else { 0 };
    prop::collection::vec(
        prop_oneof![
            4 => Just(Ev::Fire),
            5 => Just(Ev::Deliver),
            1 => Just(Ev::Drop),
            1 => Just(Ev::Duplicate),
            spont => Just(Ev::Spontaneous),
            1 => (0.0f64..2.5).prop_map(Ev::Wait),
        ],
        0..80,
    )
}

/// What the accounting said, per trigger id.
#[derive(Default, Debug)]
struct Tally {
    answered: HashMap<u64, u32>,
    missing: HashMap<u64, u32>,
    late: HashMap<u64, u32>,
    extra: u32,
    /// Frames whose verdict named the wrong trigger.
    mislabelled: u32,
}

impl Tally {
    fn faults(&self) -> u32 {
        self.missing.values().sum::<u32>() + self.late.values().sum::<u32>() + self.extra
    }
}

const TIMEOUT_S: f64 = 1.0;

/// The model rig (truth) and the accounting under test, stepped event by event.
struct Model {
    acc: TriggerAccounting,
    exact: bool,
    now: f64,
    next_id: u64,
    next_seq: u64,
    fired: Vec<u64>,
    /// Produced, not yet delivered: (sequence, owner trigger).
    queue: VecDeque<(u64, Option<u64>)>,
    last_delivered: Option<u64>,
    expired: Vec<u64>,
    dropped_since: Vec<u64>,
    tally: Tally,
    faulty: bool,
}

impl Model {
    fn new(start_seq: u64, exact: bool) -> Self {
        let mut acc = TriggerAccounting::with_wrap("cam", 1 << 32);
        acc.reset(Some(start_seq));
        Self {
            acc,
            exact,
            now: 0.0,
            next_id: 100,
            next_seq: start_seq,
            fired: Vec::new(),
            queue: VecDeque::new(),
            last_delivered: None,
            expired: Vec::new(),
            dropped_since: Vec::new(),
            tally: Tally::default(),
            faulty: false,
        }
    }

    fn expire(&mut self, now: f64) {
        for e in self.acc.expire(now) {
            match e {
                DeviceError {
                    kind:
                        DeviceErrorKind::MissingFrame {
                            trigger_id,
                            timeout_s,
                            ..
                        },
                    ..
                } => {
                    assert_eq!(timeout_s, TIMEOUT_S);
                    *self.tally.missing.entry(trigger_id).or_default() += 1;
                    self.expired.push(trigger_id);
                    self.faulty = true;
                }
                other => panic!("expire gave {other:?}"),
            }
        }
    }

    fn produce(&mut self, owner: Option<u64>) {
        self.queue.push_back((self.next_seq, owner));
        self.next_seq = (self.next_seq + 1) % (1 << 32);
    }

    fn step(&mut self, ev: &Ev) {
        match *ev {
            Ev::Fire => {
                self.acc.expect(self.next_id, self.now, TIMEOUT_S);
                self.fired.push(self.next_id);
                self.produce(Some(self.next_id));
                self.next_id += 3;
            }
            Ev::Spontaneous => {
                self.faulty = true;
                self.produce(None);
            }
            Ev::Wait(dt) => {
                self.now += dt;
                self.expire(self.now);
            }
            Ev::Drop => {
                if let Some((_, owner)) = self.queue.pop_front() {
                    self.faulty = true;
                    if let Some(t) = owner {
                        self.dropped_since.push(t);
                    }
                }
            }
            Ev::Duplicate => {
                if let Some(seq) = self.last_delivered {
                    self.faulty = true;
                    let d = self.acc.on_frame(seq);
                    assert!(d.lost.is_empty());
                    assert_eq!(d.verdict, FrameVerdict::Extra);
                    self.tally.extra += 1;
                }
            }
            Ev::Deliver => self.deliver(),
        }
    }

    fn deliver(&mut self) {
        let Some((seq, owner)) = self.queue.pop_front() else {
            return;
        };
        self.expire(self.now);
        let d = self.acc.on_frame(seq);
        self.last_delivered = Some(seq);
        for &t in &d.lost {
            *self.tally.missing.entry(t).or_default() += 1;
        }
        if self.exact {
            let want_lost: Vec<u64> = self
                .dropped_since
                .iter()
                .copied()
                .filter(|t| !self.expired.contains(t))
                .collect();
            assert_eq!(d.lost, want_lost, "lost frames before seq {seq}");
        }
        self.dropped_since.clear();
        match d.verdict {
            FrameVerdict::Answers(t) => {
                *self.tally.answered.entry(t).or_default() += 1;
                if owner != Some(t) {
                    self.tally.mislabelled += 1;
                }
                if self.exact {
                    assert_eq!(owner, Some(t));
                    assert!(!self.expired.contains(&t), "answered an expired trigger");
                }
            }
            FrameVerdict::Late(t) => {
                *self.tally.late.entry(t).or_default() += 1;
                if self.exact {
                    assert_eq!(owner, Some(t));
                    assert!(self.expired.contains(&t));
                }
            }
            FrameVerdict::Extra => {
                self.tally.extra += 1;
                assert!(!self.exact, "frame of trigger {owner:?} judged extra");
            }
        }
    }
}

/// Runs `evs`, then drains: every queued frame arrives, one last probe trigger fires and its
/// frame arrives (so trailing lost frames show as a gap), and every deadline passes.
fn run(evs: &[Ev], start_seq: u64, exact: bool) -> Model {
    let mut m = Model::new(start_seq, exact);
    for ev in evs {
        m.step(ev);
    }
    while !m.queue.is_empty() {
        m.deliver();
    }
    m.step(&Ev::Fire);
    m.deliver();
    m.expire(f64::INFINITY);
    if m.expired.iter().any(|t| m.tally.answered.contains_key(t)) {
        m.tally.mislabelled += 1;
    }
    m
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Without spontaneous frames the accounting is exact: each frame is matched to the
    /// trigger that caused it, lost frames are named, and every trigger ends up answered or
    /// reported missing exactly once.
    #[test]
    fn exact_when_the_camera_only_fires_on_triggers(
        evs in events(false),
        start in prop_oneof![Just(0u64), Just(u64::from(u32::MAX) - 3), 0u64..1000],
    ) {
        let Model { tally, faulty, fired, .. } = run(&evs, start, true);
        prop_assert_eq!(tally.mislabelled, 0);
        for t in &fired {
            let a = tally.answered.get(t).copied().unwrap_or(0);
            let m = tally.missing.get(t).copied().unwrap_or(0);
            prop_assert_eq!(a + m, 1, "trigger {} answered {} times, missing {} times", t, a, m);
            prop_assert!(tally.late.get(t).copied().unwrap_or(0) <= m);
        }
        if !faulty {
            prop_assert_eq!(tally.faults(), 0);
        }
    }

    /// With spontaneous frames the accounting cannot always tell which frame is which, but it
    /// never lets a fault pass unreported: any mislabelled frame comes with an error.
    #[test]
    fn faults_are_never_silent(evs in events(true), start in 0u64..1000) {
        let Model { tally, faulty, .. } = run(&evs, start, false);
        if tally.mislabelled > 0 {
            prop_assert!(tally.faults() > 0);
        }
        if faulty {
            prop_assert!(tally.faults() > 0, "an injected fault went unreported: {:?}", tally);
        }
    }

    /// The accounting never panics on arbitrary sequence numbers, and `frame_result` agrees
    /// with `on_frame`.
    #[test]
    fn arbitrary_sequences_never_panic(
        ops in prop::collection::vec((any::<bool>(), any::<u64>()), 0..60),
        wrap in prop_oneof![Just(0u64), Just(1 << 16), Just(1 << 32), any::<u64>()],
    ) {
        let mut a = TriggerAccounting::with_wrap("cam", wrap);
        let mut b = a.clone();
        for (i, (fire, seq)) in ops.into_iter().enumerate() {
            if fire {
                a.expect(i as u64, i as f64, 0.5);
                b.expect(i as u64, i as f64, 0.5);
            } else {
                let d = a.on_frame(seq);
                let r = b.frame_result(seq);
                match (d.lost.is_empty(), d.verdict, r) {
                    (true, FrameVerdict::Answers(t), Ok(u)) => prop_assert_eq!(t, u),
                    (false, _, Err(DeviceError { kind: DeviceErrorKind::MissingFrame { trigger_id, .. }, .. })) => {
                        prop_assert_eq!(Some(&trigger_id), d.lost.first())
                    }
                    (true, FrameVerdict::Late(t), Err(DeviceError { kind: DeviceErrorKind::UnexpectedFrame { got, .. }, .. })) => {
                        prop_assert_eq!(t, got)
                    }
                    (true, FrameVerdict::Extra, Err(DeviceError { kind: DeviceErrorKind::UnexpectedFrame { .. }, .. })) => {}
                    (l, v, r) => prop_assert!(false, "disagree: lost empty {l}, {v:?}, {r:?}"),
                }
            }
            a.expire(i as f64);
            b.expire(i as f64);
        }
    }
}

#[test]
fn a_frame_answers_the_pending_trigger() {
    let mut a = TriggerAccounting::new("cam0");
    a.expect(7, 0.0, frame_timeout_s(0.1, 0.05));
    assert_eq!(a.frame_result(41), Ok(7));
    assert_eq!(a.waiting(), 0);
}

#[test]
fn a_frame_without_trigger_is_unexpected() {
    let mut a = TriggerAccounting::new("cam0");
    a.expect(7, 0.0, 1.0);
    assert_eq!(a.frame_result(1), Ok(7));
    let err = a.frame_result(2).unwrap_err();
    assert!(
        matches!(err, DeviceError { ref device, kind: DeviceErrorKind::UnexpectedFrame { .. } } if device == "cam0")
    );
}

#[test]
fn a_sequence_jump_is_a_missing_frame() {
    let mut a = TriggerAccounting::new("cam0");
    a.expect(1, 0.0, 1.0);
    a.expect(2, 0.0, 1.0);
    a.expect(3, 0.0, 1.0);
    assert_eq!(a.frame_result(10), Ok(1));
    // Sequence 11 was lost: it was trigger 2's frame; 12 answers trigger 3.
    let err = a.frame_result(12).unwrap_err();
    assert!(
        matches!(
            err,
            DeviceError {
                kind: DeviceErrorKind::MissingFrame { trigger_id: 2, .. },
                ..
            }
        ),
        "{err:?}"
    );
    assert_eq!(a.waiting(), 0);
}

#[test]
fn a_trigger_without_frame_times_out_and_its_late_frame_is_rejected() {
    let mut a = TriggerAccounting::new("cam0");
    let timeout = frame_timeout_s(0.2, 0.1);
    a.expect(5, 10.0, timeout);
    assert_eq!(a.next_deadline_s(), Some(10.0 + timeout));
    assert!(a.expire(10.0 + timeout - 0.01).is_empty());
    let errs = a.expire(10.0 + timeout);
    assert_eq!(
        errs,
        vec![DeviceError::new(
            "cam0",
            DeviceErrorKind::MissingFrame {
                trigger_id: 5,
                timeout_s: timeout
            }
        )]
    );
    assert!(a.expire(100.0).is_empty(), "reported once");
    a.expect(6, 20.0, timeout);
    // Trigger 5's frame finally arrives: late, must not answer trigger 6.
    let err = a.frame_result(0).unwrap_err();
    assert_eq!(
        err,
        DeviceError::new(
            "cam0",
            DeviceErrorKind::UnexpectedFrame {
                expected: 6,
                got: 5
            }
        )
    );
    assert_eq!(a.frame_result(1), Ok(6));
}
