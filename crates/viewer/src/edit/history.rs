//! Undo and redo as snapshots of the edited state. Snapshots are cheap: masks are shared
//! (`Arc`) between them and copied only when painted.

/// How many steps back undo reaches.
const DEPTH: usize = 100;

/// The committed state and the snapshots before and after it.
#[derive(Debug)]
pub struct History<T> {
    committed: T,
    undo: Vec<T>,
    redo: Vec<T>,
}

impl<T: Clone + PartialEq> History<T> {
    pub fn new(state: T) -> Self {
        Self {
            committed: state,
            undo: Vec::new(),
            redo: Vec::new(),
        }
    }

    /// Records `current` as one step if it differs from the committed state (called once
    /// an edit is finished: a stroke, a drag, a rename). Returns whether it did.
    pub fn commit(&mut self, current: &T) -> bool {
        if *current == self.committed {
            return false;
        }
        let before = std::mem::replace(&mut self.committed, current.clone());
        self.undo.push(before);
        if self.undo.len() > DEPTH {
            self.undo.remove(0);
        }
        self.redo.clear();
        true
    }

    /// Replaces the committed state without a step: for changes that are not edits (the
    /// file names saving gave to painted masks).
    pub fn amend(&mut self, current: &T) {
        self.committed = current.clone();
    }

    /// The state before the last step (committing `current` first), or None.
    pub fn undo(&mut self, current: &T) -> Option<T> {
        self.commit(current);
        let previous = self.undo.pop()?;
        self.redo
            .push(std::mem::replace(&mut self.committed, previous.clone()));
        Some(previous)
    }

    /// The state the last undo left, or None.
    pub fn redo(&mut self, current: &T) -> Option<T> {
        if *current != self.committed {
            return None; // an edit since the undo: there is nothing to redo
        }
        let next = self.redo.pop()?;
        self.undo
            .push(std::mem::replace(&mut self.committed, next.clone()));
        Some(next)
    }

    pub fn can_undo(&self, current: &T) -> bool {
        !self.undo.is_empty() || *current != self.committed
    }

    pub fn can_redo(&self, current: &T) -> bool {
        !self.redo.is_empty() && *current == self.committed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undo_and_redo_walk_the_committed_steps() {
        let mut h = History::new(vec![0]);
        assert!(!h.commit(&vec![0]), "no change, no step");
        assert!(h.commit(&vec![0, 1]));
        assert!(h.commit(&vec![0, 1, 2]));
        // An uncommitted change is undone first.
        assert_eq!(h.undo(&vec![9]), Some(vec![0, 1, 2]));
        assert_eq!(h.undo(&vec![0, 1, 2]), Some(vec![0, 1]));
        assert_eq!(h.undo(&vec![0, 1]), Some(vec![0]));
        assert_eq!(h.undo(&vec![0]), None);
        assert_eq!(h.redo(&vec![0]), Some(vec![0, 1]));
        assert_eq!(h.redo(&vec![0, 1]), Some(vec![0, 1, 2]));
        // A new edit after an undo drops the redo steps.
        assert_eq!(h.undo(&vec![0, 1, 2]), Some(vec![0, 1]));
        assert!(h.commit(&vec![5]));
        assert_eq!(h.redo(&vec![5]), None);
        assert!(!h.can_redo(&vec![5]) && h.can_undo(&vec![5]));
    }
}
