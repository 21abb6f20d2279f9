//! The threaded form of [`super::evaluate_frames`]: SUMO and
//! sensing go on in the calling thread while a scoped pool evaluates
//! (step, runner) tasks; a reorder buffer hands the results on in step
//! order, with at most 2 x threads steps in flight.

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};

use super::evaluation::{Evaluation, OnEval};
use super::simulate::{Step, simulate_steps};
use super::{Progress, RunError, SimStats, Warnings};
use crate::config::Settings;
use crate::evaluate::{CorrespondenceSource, FrameEval};

/// One task: a runner on a step.
struct Task {
    seq: usize,
    step: Arc<Step>,
    runner: usize,
}

/// A finished task (`None`: it panicked).
struct Done {
    seq: usize,
    runner: usize,
    evals: Option<Vec<FrameEval>>,
}

/// A step handed out, with the evaluations that are in (one slot per
/// runner).
struct Pending<S, E> {
    step: S,
    evals: Vec<Option<E>>,
}

/// The reorder buffer: steps handed out and not yet handed on, by sequence
/// number; a step is handed on once every runner's evaluation of it is in
/// and every step before it has been handed on.
struct InFlight<S, E> {
    runners: usize,
    /// The sequence number of the next step to take in, and to hand on.
    taken: usize,
    next: usize,
    steps: BTreeMap<usize, Pending<S, E>>,
}

impl<S, E> InFlight<S, E> {
    fn new(runners: usize) -> Self {
        Self {
            runners,
            taken: 0,
            next: 0,
            steps: BTreeMap::new(),
        }
    }

    /// Takes `step` in; returns its sequence number.
    fn take(&mut self, step: S) -> usize {
        let evals = (0..self.runners).map(|_| None).collect();
        let seq = self.taken;
        self.steps.insert(seq, Pending { step, evals });
        self.taken += 1;
        seq
    }

    /// Steps taken in and not yet handed on.
    fn len(&self) -> usize {
        self.steps.len()
    }

    /// CorrespondenceSource `runner`'s evaluation of step `seq` (`None`: it panicked).
    fn put(&mut self, seq: usize, runner: usize, evals: Option<E>) -> Result<(), RunError> {
        let evals = evals.ok_or_else(|| {
            RunError::Worker("an evaluation thread panicked (a bug: please report it)".into())
        })?;
        let pending = self
            .steps
            .get_mut(&seq)
            .expect("a task of a step in flight");
        pending.evals[runner] = Some(evals);
        Ok(())
    }

    /// Hands on every complete step at the front, in order, with its
    /// evaluations in runner order.
    fn hand_on_ready(
        &mut self,
        mut hand_on: impl FnMut(S, Vec<E>) -> Result<(), RunError>,
    ) -> Result<(), RunError> {
        while let Some(entry) = self.steps.first_entry() {
            if *entry.key() != self.next || entry.get().evals.iter().any(Option::is_none) {
                break;
            }
            let Pending { step, evals } = entry.remove();
            hand_on(step, evals.into_iter().map(Option::unwrap).collect())?;
            self.next += 1;
        }
        Ok(())
    }
}

fn worker(
    eval: &Evaluation,
    runners: &[CorrespondenceSource],
    tasks: &Mutex<Receiver<Task>>,
    done: Sender<Done>,
) {
    loop {
        let task = match tasks.lock() {
            Ok(rx) => rx.recv(),
            Err(_) => return,
        };
        let Ok(t) = task else { return };
        let evals = catch_unwind(AssertUnwindSafe(|| eval.step(&t.step, &runners[t.runner]))).ok();
        let d = Done {
            seq: t.seq,
            runner: t.runner,
            evals,
        };
        if done.send(d).is_err() {
            return;
        }
    }
}

/// [`super::evaluate_frames`] on `threads` threads.
pub(super) fn evaluate_frames(
    settings: &Settings,
    runners: &[CorrespondenceSource],
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    on_eval: &mut OnEval,
) -> Result<SimStats, RunError> {
    // Steps sensed ahead of the one handed on next: enough to keep every
    // thread busy, few enough to bound the memory.
    let max_in_flight = 2 * threads;
    let (task_tx, task_rx) = mpsc::channel::<Task>();
    let (done_tx, done_rx) = mpsc::channel::<Done>();
    let task_rx = Mutex::new(task_rx);
    let mut flight = InFlight::new(runners.len());
    let eval = Evaluation::of(settings);
    let mut ready = |flight: &mut Flight| {
        flight.hand_on_ready(|step, evals| eval.hand_on(&step, evals, on_eval))
    };
    std::thread::scope(|scope| {
        for k in 0..threads {
            let done = done_tx.clone();
            let tasks = &task_rx;
            let started = std::thread::Builder::new()
                .name(format!("coid-eval-{k}"))
                .spawn_scoped(scope, move || worker(&eval, runners, tasks, done));
            if let Err(e) = started {
                // The threads already started end once the queue closes.
                drop(task_tx);
                return Err(RunError::Worker(format!(
                    "cannot start evaluation thread {} of {threads}: {e} (use fewer --threads)",
                    k + 1
                )));
            }
        }
        drop(done_tx);
        let result = simulate_steps(settings, warnings, progress, |step| {
            let step = Arc::new(step);
            let seq = flight.take(Arc::clone(&step));
            for runner in 0..runners.len() {
                let t = Task {
                    seq,
                    step: Arc::clone(&step),
                    runner,
                };
                task_tx
                    .send(t)
                    .map_err(|_| RunError::Worker("the evaluation threads ended early".into()))?;
            }
            while let Ok(d) = done_rx.try_recv() {
                flight.put(d.seq, d.runner, d.evals)?;
            }
            ready(&mut flight)?;
            while flight.len() >= max_in_flight {
                wait_one(&done_rx, &mut flight)?;
                ready(&mut flight)?;
            }
            Ok(())
        });
        // No more tasks: the threads end once the queue is empty.
        drop(task_tx);
        let stats = result?;
        while flight.len() > 0 {
            wait_one(&done_rx, &mut flight)?;
            ready(&mut flight)?;
        }
        Ok(stats)
    })
}

/// The reorder buffer of [`evaluate_frames`].
type Flight = InFlight<Arc<Step>, Vec<FrameEval>>;

/// Waits for one task to finish and puts its evaluations in.
fn wait_one(rx: &Receiver<Done>, flight: &mut Flight) -> Result<(), RunError> {
    let d = rx
        .recv()
        .map_err(|_| RunError::Worker("the evaluation threads ended early".into()))?;
    flight.put(d.seq, d.runner, d.evals)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steps are handed on in the order they were taken in, each once all
    /// its runners' evaluations are in (in runner order), whatever order
    /// the evaluations arrive in.
    #[test]
    fn the_reorder_buffer_hands_steps_on_in_order_once_complete() {
        let mut flight: InFlight<&'static str, u32> = InFlight::new(2);
        assert_eq!(
            (flight.take("s0"), flight.take("s1"), flight.take("s2")),
            (0, 1, 2)
        );
        let mut out = Vec::new();
        let mut hand = |flight: &mut InFlight<&'static str, u32>| {
            flight.hand_on_ready(|s, e| {
                out.push((s, e));
                Ok(())
            })
        };
        flight.put(1, 0, Some(10)).unwrap();
        flight.put(1, 1, Some(11)).unwrap();
        flight.put(0, 1, Some(1)).unwrap();
        hand(&mut flight).unwrap();
        assert_eq!(flight.len(), 3, "step 0 lacks runner 0");
        flight.put(0, 0, Some(0)).unwrap();
        hand(&mut flight).unwrap();
        assert_eq!(flight.len(), 1);
        flight.put(2, 1, Some(21)).unwrap();
        flight.put(2, 0, Some(20)).unwrap();
        hand(&mut flight).unwrap();
        assert_eq!(flight.len(), 0);
        assert_eq!(
            out,
            [
                ("s0", vec![0, 1]),
                ("s1", vec![10, 11]),
                ("s2", vec![20, 21])
            ]
        );
    }

    /// A task that panicked is an error, not a missing result waited for
    /// forever.
    #[test]
    fn a_panicked_task_is_an_error() {
        let mut flight: InFlight<(), u32> = InFlight::new(1);
        let seq = flight.take(());
        match flight.put(seq, 0, None) {
            Err(RunError::Worker(why)) => assert!(why.contains("panicked"), "{why}"),
            other => panic!("{other:?}"),
        }
    }
}
