//! HTTP + websocket API (axum): translation only, no science.
