//! CPU work that answers in one piece (`/v1/trace`, `/v1/grade`), run like a render: it
//! takes a render slot from [`super::admission`] (503 with `Retry-After` when saturated,
//! 504 when the deadline passes in the queue), runs on the rayon pool in its turn in the
//! pool's queue ([`crate::render::Scheduler`], behind the tiles already queued rather
//! than behind whole renders), never on tokio's threads, and frees the slot only when
//! the work is over.
//!
//! Nothing is streamed, so the status line waits for the result; while it waits, three
//! things can end the request first: the deadline (504), the end of the shutdown grace
//! period (503), and the client leaving (the handler is dropped). Each raises the job's
//! [`Cancel`] flag, which stops a reference render between tiles; work that cannot stop
//! (explaining one pixel) finishes on its own and is thrown away, still holding its slot
//! so that admission counts what really runs.
//!
//! The flag also carries the ray budget of [`CostLimit::token`]: work that renders (the
//! reference of a grade) is checked first with [`CostLimit::check`], and stopped once
//! it traces half as much again as `--max-rays` (outcome `over_budget`).

use std::panic::AssertUnwindSafe;
use std::time::Instant;

use tokio::sync::oneshot;

use super::AppState;
use super::admission::CostLimit;
use super::error::ApiError;
use super::extract::{RequestInfo, deadline_exceeded};
use super::shutdown::Phase;
use crate::render::Cancel;

/// Raises the flag when dropped: when the handler ends early (deadline, shutdown, or a
/// client that left, which drops the handler's future), the work should stop too.
struct CancelOnDrop(Cancel);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.cancel();
    }
}

/// Runs `work` on the rayon pool once a render slot is free, and returns what it
/// returns. `label` names it in `raytile_render_duration_seconds{output}`.
///
/// The work gets the cancel flag that the deadline, the shutdown, a departed client and
/// the ray budget raise. A panic in it is caught and answered as 500 (a fault of ours).
pub async fn run<T, F>(
    app: &AppState,
    info: &RequestInfo,
    label: &'static str,
    work: F,
) -> Result<T, ApiError>
where
    T: Send + 'static,
    F: FnOnce(&Cancel) -> T + Send + 'static,
{
    let deadline = tokio::time::Instant::from_std(info.start + app.config.deadline());
    let slot = tokio::time::timeout_at(deadline, app.admission.admit(&app.shutdown))
        .await
        .map_err(|_| deadline_exceeded(app))??;
    let cancel = CostLimit::new(&app.config).token();
    let _stop_when_gone = CancelOnDrop(cancel.clone());
    let (tx, rx) = oneshot::channel();
    let job_cancel = cancel.clone();
    let metrics = app.metrics.clone();
    let span = tracing::Span::current();
    app.pool.spawn(move || {
        let _enter = span.enter();
        let started = Instant::now();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| work(&job_cancel)));
        let outcome = match &result {
            Err(_) => "failed",
            Ok(_) if job_cancel.is_over_budget() => "over_budget",
            Ok(_) if job_cancel.is_cancelled() => "cancelled",
            Ok(_) => "complete",
        };
        metrics
            .render_duration(label, outcome)
            .observe(started.elapsed().as_secs_f64());
        // Free the slot before handing the result over, so that a client which sends its
        // next request as soon as it has this answer finds the slot free.
        drop(slot);
        // The handler may be gone (deadline, client left): then nobody wants the result.
        let _ = tx.send(result);
    });
    tokio::select! {
        // A finished result wins over a timer that fires at the same moment.
        biased;
        r = rx => match r {
            Ok(Ok(t)) => Ok(t),
            Ok(Err(_)) => {
                tracing::error!(job = label, "a job panicked");
                Err(ApiError::Internal(format!("the {label} job panicked")))
            }
            Err(_) => Err(ApiError::Internal(format!("the {label} job ended without an answer"))),
        },
        _ = tokio::time::sleep_until(deadline) => {
            cancel.cancel();
            Err(deadline_exceeded(app))
        }
        _ = app.shutdown.reached(Phase::Stopping) => {
            cancel.cancel();
            Err(ApiError::ShuttingDown)
        }
    }
}
