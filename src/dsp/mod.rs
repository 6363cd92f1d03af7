//! Signal processing: band-limited differentiation, FFT helpers, transfer functions, harmonic analysis, least squares. Pure.
