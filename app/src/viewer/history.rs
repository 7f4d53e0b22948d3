//! Undo and redo of edits.
//!
//! How it works: the viewer records a snapshot of everything a user edits (the scene's fabric,
//! materials and mesh, the lights, the render settings) once per frame in which no pointer
//! button is held, so a whole slider drag or a sphere-widget drag is one step.
//! [`History::record`] pushes the previously recorded state onto the undo stack when the new one
//! differs, and clears the redo stack (a new edit forks history). Undo and redo swap states
//! between the two stacks; the viewer applies the state they return, and its usual change
//! detection reruns only what that state's differences need (a material undo reruns the
//! material tables, a light undo nothing but the picture).

/// Most undo steps kept.
pub const MAX_UNDO: usize = 200;

/// Undo and redo stacks of states of type `T`.
pub struct History<T> {
    undo: Vec<T>,
    redo: Vec<T>,
    recorded: Option<T>,
}

impl<T> Default for History<T> {
    fn default() -> Self {
        Self { undo: Vec::new(), redo: Vec::new(), recorded: None }
    }
}

impl<T: Clone + PartialEq> History<T> {
    /// Records `current` as the state after an edit (nothing happens if it did not change).
    pub fn record(&mut self, current: &T) {
        match &self.recorded {
            Some(last) if last == current => {}
            Some(last) => {
                self.undo.push(last.clone());
                if self.undo.len() > MAX_UNDO {
                    self.undo.remove(0);
                }
                self.redo.clear();
                self.recorded = Some(current.clone());
            }
            None => self.recorded = Some(current.clone()),
        }
    }

    /// Forgets every step and starts from `current` (a newly loaded scene).
    pub fn reset(&mut self, current: &T) {
        self.undo.clear();
        self.redo.clear();
        self.recorded = Some(current.clone());
    }

    /// The state before the last edit, if any; `current` becomes redoable.
    pub fn undo(&mut self, current: &T) -> Option<T> {
        self.record(current);
        let previous = self.undo.pop()?;
        self.redo.push(current.clone());
        self.recorded = Some(previous.clone());
        Some(previous)
    }

    /// The state the last undo left, if any.
    pub fn redo(&mut self, current: &T) -> Option<T> {
        if self.recorded.as_ref() != Some(current) {
            // An edit since the undo: there is nothing to redo.
            self.record(current);
            return None;
        }
        let next = self.redo.pop()?;
        self.undo.push(current.clone());
        self.recorded = Some(next.clone());
        Some(next)
    }

    #[must_use]
    pub fn can_undo(&self, current: &T) -> bool {
        !self.undo.is_empty() || self.recorded.as_ref().is_some_and(|r| r != current)
    }

    #[must_use]
    pub fn can_redo(&self) -> bool {
        !self.redo.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undo_and_redo_walk_the_recorded_states() {
        let mut h = History::default();
        h.record(&1);
        h.record(&1);
        h.record(&2);
        h.record(&3);
        assert!(h.can_undo(&3) && !h.can_redo());
        assert_eq!(h.undo(&3), Some(2));
        assert_eq!(h.undo(&2), Some(1));
        assert_eq!(h.undo(&1), None);
        assert_eq!(h.redo(&1), Some(2));
        assert_eq!(h.redo(&2), Some(3));
        assert_eq!(h.redo(&3), None);
    }

    #[test]
    fn an_edit_after_undo_clears_redo_and_an_unrecorded_edit_is_undoable() {
        let mut h = History::default();
        h.record(&"a");
        h.record(&"b");
        assert_eq!(h.undo(&"b"), Some("a"));
        h.record(&"c");
        assert!(!h.can_redo());
        assert_eq!(h.redo(&"c"), None);
        // An edit still in progress (not yet recorded) is undone to the last recorded state.
        assert!(h.can_undo(&"d"));
        assert_eq!(h.undo(&"d"), Some("c"));
        assert_eq!(h.redo(&"c"), Some("d"));
    }

    #[test]
    fn the_stack_is_bounded_and_reset_forgets_everything() {
        let mut h = History::default();
        for i in 0..=MAX_UNDO + 10 {
            h.record(&i);
        }
        let mut steps = 0;
        let mut current = MAX_UNDO + 10;
        while let Some(previous) = h.undo(&current) {
            current = previous;
            steps += 1;
        }
        assert_eq!(steps, MAX_UNDO);
        h.reset(&7);
        assert!(!h.can_undo(&7) && !h.can_redo());
    }
}
