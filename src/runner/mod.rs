//! Runner: one task owns each bench, queues and executes jobs, emits events.
