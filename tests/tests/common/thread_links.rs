//! Slabs on threads: the tests' stand-in for the MPI ranks of the slab solves and the flow
//! on slabs (core/src/flow/cycle_slab.rs `Links`), and the comparison of a slab's rows with
//! the serial run's.

use sieve_core::flow::cycle_slab::Links;
use sieve_core::sum;
use sieve_core::Real;
use std::sync::{mpsc, Arc, Barrier, Mutex};

/// Slabs on threads, the tests' stand-in for MPI ranks (core/src/flow/cycle_slab.rs
/// `Links`): a channel per direction between neighbours, a shared board for the gathers.
pub struct ThreadLinks<R = f64> {
    index: usize,
    up: Option<mpsc::Sender<Vec<R>>>,
    down: Option<mpsc::Sender<Vec<R>>>,
    from_below: Option<mpsc::Receiver<Vec<R>>>,
    from_above: Option<mpsc::Receiver<Vec<R>>>,
    board: Arc<(Mutex<Vec<Vec<R>>>, Barrier)>,
}

impl<R: Real> ThreadLinks<R> {
    /// The links of `slabs` slabs, in slab order.
    pub fn chain(slabs: usize) -> Vec<Self> {
        let board = Arc::new((Mutex::new(vec![vec![]; slabs]), Barrier::new(slabs)));
        let mut links: Vec<Self> = (0..slabs)
            .map(|index| Self {
                index,
                up: None,
                down: None,
                from_below: None,
                from_above: None,
                board: board.clone(),
            })
            .collect();
        for k in 1..slabs {
            let (tx, rx) = mpsc::channel();
            links[k - 1].up = Some(tx);
            links[k].from_below = Some(rx);
            let (tx, rx) = mpsc::channel();
            links[k].down = Some(tx);
            links[k - 1].from_above = Some(rx);
        }
        links
    }
}

impl<R: Real> Links<R> for ThreadLinks<R> {
    fn send_up(&mut self, row: &[R]) {
        self.up
            .as_ref()
            .expect("a slab above")
            .send(row.to_vec())
            .unwrap();
    }
    fn send_down(&mut self, row: &[R]) {
        self.down
            .as_ref()
            .expect("a slab below")
            .send(row.to_vec())
            .unwrap();
    }
    fn receive_below(&mut self, row: &mut [R]) {
        row.copy_from_slice(
            &self
                .from_below
                .as_ref()
                .expect("a slab below")
                .recv()
                .unwrap(),
        );
    }
    fn receive_above(&mut self, row: &mut [R]) {
        row.copy_from_slice(
            &self
                .from_above
                .as_ref()
                .expect("a slab above")
                .recv()
                .unwrap(),
        );
    }
    fn swap(&mut self, bottom: &[R], top: &[R], below: &mut [R], above: &mut [R]) {
        if let Some(d) = &self.down {
            d.send(bottom.to_vec()).unwrap();
        }
        if let Some(u) = &self.up {
            u.send(top.to_vec()).unwrap();
        }
        if let Some(r) = &self.from_below {
            below.copy_from_slice(&r.recv().unwrap());
        }
        if let Some(r) = &self.from_above {
            above.copy_from_slice(&r.recv().unwrap());
        }
    }
    fn gather(&mut self, own: &[R], all: &mut [R]) {
        let (board, barrier) = &*self.board;
        board.lock().unwrap()[self.index] = own.to_vec();
        barrier.wait();
        all.copy_from_slice(&board.lock().unwrap().concat());
        barrier.wait();
    }
    fn sum(&mut self, own: &[R]) -> R {
        let (board, barrier) = &*self.board;
        board.lock().unwrap()[self.index] = own.to_vec();
        barrier.wait();
        let all = board.lock().unwrap().concat();
        barrier.wait();
        sum::sum(&all)
    }
}

/// Asserts that a slab's owned `mine` (global cells from `first`) has the serial bits of
/// `all` (the whole grid's array `name`), naming the first cell that differs with its row and
/// column (`plane` cells per row) in the words of issue 12 ("name the first step where two
/// decompositions diverge"; `at` names the scene, the cut, the step and the slab).
pub fn assert_serial_rows(
    at: &str,
    name: &str,
    mine: &[f64],
    all: &[f64],
    first: usize,
    plane: usize,
) {
    let serial = &all[first..first + mine.len()];
    if let Some(j) = (0..mine.len()).find(|&j| mine[j].to_bits() != serial[j].to_bits()) {
        let cell = first + j;
        panic!(
            "{at}: first divergence in {name} at cell {cell} (row {}, column {}): \
             {} on the slab, {} serially",
            cell / plane,
            cell % plane,
            mine[j],
            serial[j]
        );
    }
}

/// Runs `slab(k, links)` for each of `slabs` slabs on its own thread, as MPI ranks would run
/// them, and returns the results in slab order (64 MiB stacks: a step's frames are deep).
pub fn on_threads<R: Real, T: Send>(
    slabs: usize,
    slab: impl Fn(usize, ThreadLinks<R>) -> T + Sync,
) -> Vec<T> {
    let slab = &slab;
    std::thread::scope(|scope| {
        let handles: Vec<_> = ThreadLinks::chain(slabs)
            .into_iter()
            .enumerate()
            .map(|(k, links)| {
                std::thread::Builder::new()
                    .stack_size(64 << 20)
                    .spawn_scoped(scope, move || slab(k, links))
                    .unwrap()
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}
