//! One generation at a time: the model lives on its own thread and takes jobs from a bounded
//! queue; a request that finds the queue full is answered 503 at once instead of waiting.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, SyncSender, TrySendError};
use std::sync::Arc;

use crate::engine::Engine;
use crate::error::{ApiError, ServeError};

type EngineJob = Box<dyn FnOnce(&mut Engine) + Send>;

/// The handle requests use to run work on the model's thread.
#[derive(Clone)]
pub struct Worker {
    tx: SyncSender<EngineJob>,
    /// Jobs sent and not yet finished (the running one included).
    pending: Arc<AtomicUsize>,
    /// Jobs finished since the start.
    done: Arc<AtomicUsize>,
}

impl Worker {
    /// Start the model's thread: `load` runs there (the model never crosses threads); its
    /// error is returned here. `queue` jobs may wait behind the running one.
    pub fn start(
        load: impl FnOnce() -> Result<Engine, ServeError> + Send + 'static,
        queue: usize,
    ) -> Result<(Worker, crate::api::Limits, usize), ServeError> {
        let (tx, rx) = mpsc::sync_channel::<EngineJob>(queue);
        let (ready_tx, ready_rx) = mpsc::channel();
        let pending = Arc::new(AtomicUsize::new(0));
        let done = Arc::new(AtomicUsize::new(0));
        let (p, d) = (pending.clone(), done.clone());
        std::thread::Builder::new().name("diffkfc-model".into()).spawn(move || {
            let mut engine = match load() {
                Ok(e) => {
                    let _ = ready_tx.send(Ok((e.limits.clone(), e.step())));
                    e
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                    return;
                }
            };
            for job in rx {
                // A panicking job drops its reply sender: that request gets a 500 and the
                // model keeps serving the others. A job that returns has counted itself done
                // before answering, so a client never sees its own request pending.
                let ran =
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job(&mut engine)));
                if ran.is_err() {
                    p.fetch_sub(1, Ordering::SeqCst);
                    d.fetch_add(1, Ordering::SeqCst);
                }
            }
        })?;
        let (mut limits, step) = ready_rx
            .recv()
            .map_err(|_| ServeError::Load("the model thread stopped while loading".into()))??;
        limits.queue = queue;
        Ok((Worker { tx, pending, done }, limits, step))
    }

    /// Run `f` on the model's thread and wait for its answer; 503 when the queue is full.
    pub async fn run<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Engine) -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        let (pending, done) = (self.pending.clone(), self.done.clone());
        let job: EngineJob = Box::new(move |e| {
            let out = f(e);
            pending.fetch_sub(1, Ordering::SeqCst);
            done.fetch_add(1, Ordering::SeqCst);
            let _ = reply.send(out);
        });
        self.pending.fetch_add(1, Ordering::SeqCst);
        if let Err(e) = self.tx.try_send(job) {
            let queued = self.pending.fetch_sub(1, Ordering::SeqCst) - 1;
            return Err(match e {
                TrySendError::Full(_) => ApiError::busy(queued),
                TrySendError::Disconnected(_) => ApiError::internal("the model thread stopped"),
            });
        }
        answer.await.map_err(|_| ApiError::internal("generation failed (see the server's log)"))?
    }

    /// Jobs queued or running, and jobs finished.
    pub fn load(&self) -> (usize, usize) {
        (self.pending.load(Ordering::SeqCst), self.done.load(Ordering::SeqCst))
    }
}
