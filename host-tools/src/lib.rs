//! slipguard host tools (data layer arrives with the data issue).
