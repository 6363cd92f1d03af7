//! Physical effects beyond the basic force balance: ids, parameters and meanings shared by the virtual bench (simulation) and the diagnostics (identification).
