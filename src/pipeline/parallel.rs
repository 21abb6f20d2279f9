//! The threaded form of [`super::frames::evaluate_frames`]: SUMO and
//! sensing go on in the calling thread while a scoped pool evaluates
//! (step, runner) tasks; a reorder buffer hands the results on in step
//! order, with at most 2 x threads steps in flight.

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};

use super::frames::{OnEval, evaluate_step, hand_on};
use super::simulate::{Step, simulate_steps};
use super::{Progress, RunError, SimStats};
use crate::config::Settings;
use crate::evaluate::{FrameEval, Runner};

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
struct Pending {
    step: Arc<Step>,
    evals: Vec<Option<Vec<FrameEval>>>,
}

/// Steps handed out and not yet handed on, by sequence number.
struct InFlight {
    runners: usize,
    next: usize,
    steps: BTreeMap<usize, Pending>,
}

impl InFlight {
    fn put(&mut self, d: Done) -> Result<(), RunError> {
        let evals = d.evals.ok_or_else(|| {
            RunError::Worker("an evaluation thread panicked (a bug: please report it)".into())
        })?;
        let pending = self
            .steps
            .get_mut(&d.seq)
            .expect("a task of a step in flight");
        pending.evals[d.runner] = Some(evals);
        Ok(())
    }

    /// Hands on every complete step at the front, in order.
    fn hand_on_ready(&mut self, settings: &Settings, on_eval: &mut OnEval) -> Result<(), RunError> {
        while let Some(entry) = self.steps.first_entry() {
            if *entry.key() != self.next || entry.get().evals.iter().any(Option::is_none) {
                break;
            }
            let Pending { step, evals } = entry.remove();
            let evals = evals.into_iter().map(Option::unwrap).collect();
            hand_on(settings, &step, evals, on_eval)?;
            self.next += 1;
        }
        Ok(())
    }
}

fn worker(
    settings: &Settings,
    runners: &[Runner],
    tasks: &Mutex<Receiver<Task>>,
    done: Sender<Done>,
) {
    loop {
        let task = match tasks.lock() {
            Ok(rx) => rx.recv(),
            Err(_) => return,
        };
        let Ok(t) = task else { return };
        let evals = catch_unwind(AssertUnwindSafe(|| {
            evaluate_step(settings, &t.step, &runners[t.runner])
        }))
        .ok();
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

/// [`super::frames::evaluate_frames`] on `threads` threads.
pub(super) fn evaluate_frames(
    settings: &Settings,
    runners: &[Runner],
    threads: usize,
    progress: impl FnMut(Progress),
    on_eval: &mut OnEval,
) -> Result<SimStats, RunError> {
    // Steps sensed ahead of the one handed on next: enough to keep every
    // thread busy, few enough to bound the memory.
    let max_in_flight = 2 * threads;
    let (task_tx, task_rx) = mpsc::channel::<Task>();
    let (done_tx, done_rx) = mpsc::channel::<Done>();
    let task_rx = Mutex::new(task_rx);
    let mut flight = InFlight {
        runners: runners.len(),
        next: 0,
        steps: BTreeMap::new(),
    };
    std::thread::scope(|scope| {
        for k in 0..threads {
            let done = done_tx.clone();
            let tasks = &task_rx;
            let started = std::thread::Builder::new()
                .name(format!("coid-eval-{k}"))
                .spawn_scoped(scope, move || worker(settings, runners, tasks, done));
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
        let mut seq = 0;
        let result = simulate_steps(settings, progress, |step| {
            let step = Arc::new(step);
            let evals = (0..flight.runners).map(|_| None).collect();
            let pending = Pending {
                step: Arc::clone(&step),
                evals,
            };
            flight.steps.insert(seq, pending);
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
            seq += 1;
            while let Ok(d) = done_rx.try_recv() {
                flight.put(d)?;
            }
            flight.hand_on_ready(settings, on_eval)?;
            while flight.steps.len() >= max_in_flight {
                wait_one(&done_rx, &mut flight)?;
                flight.hand_on_ready(settings, on_eval)?;
            }
            Ok(())
        });
        // No more tasks: the threads end once the queue is empty.
        drop(task_tx);
        let stats = result?;
        while !flight.steps.is_empty() {
            wait_one(&done_rx, &mut flight)?;
            flight.hand_on_ready(settings, on_eval)?;
        }
        Ok(stats)
    })
}

fn wait_one(rx: &Receiver<Done>, flight: &mut InFlight) -> Result<(), RunError> {
    let d = rx
        .recv()
        .map_err(|_| RunError::Worker("the evaluation threads ended early".into()))?;
    flight.put(d)
}
