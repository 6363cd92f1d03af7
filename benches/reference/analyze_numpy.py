#!/usr/bin/env python3
"""The reference for `springbench analyze DIR` in numpy (issue 38): the same
fit of a recording set, written the way a lab script would write it, to pair
the whole process against (docs/performance.md, "analyze against numpy").

Steps, as the analysis does them: read pre.wav and main.wav (IEEE float32,
3 channels); small-signal fit of the pre-measurement (whole-record FFT of
displacement and microphone, linear resonator m w^2 X = k0 X + j w R X - A M
by least squares over the excited band); the main sweep band-limited to
1200 Hz and differentiated in the frequency domain (x, v, a, mic), decimated;
the Two Signal force balance m a = -sum k_i x^(i+1) - R v + s mic by least
squares for K(x) orders 1..8, the order chosen by the BIC; Keff at the
displacement peak. Prints one JSON document.

    python3 benches/reference/analyze_numpy.py DIR
"""
import json
import sys

import numpy as np


def read_wav_f32(path):
    with open(path, "rb") as f:
        data = f.read()
    pos, channels, rate, frames = 12, None, None, None
    while pos < len(data):
        cid, size = data[pos:pos + 4], int.from_bytes(data[pos + 4:pos + 8], "little")
        body = pos + 8
        if cid == b"fmt ":
            channels = int.from_bytes(data[body + 2:body + 4], "little")
            rate = int.from_bytes(data[body + 4:body + 8], "little")
        elif cid == b"data":
            frames = np.frombuffer(data, dtype="<f4", count=size // 4, offset=body)
            break
        pos = body + size + (size & 1)
    return rate, frames.reshape(-1, channels).astype(np.float64).T


def next_pow2(n):
    return 1 << int(np.ceil(np.log2(n)))


def small_signal(pre, fs, mass, ch):
    x, mic = pre[ch["displacement"]], pre[ch["microphone"]]
    n = next_pow2(len(x) + 64)
    X, M = np.fft.rfft(x, n), np.fft.rfft(mic, n)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    band = (f >= 8.0) & (f <= 80.0)
    Xb, Mb, w = X[band], M[band], 2 * np.pi * f[band]
    # -m w^2 X = -k0 X - j w R X + A M  (unknowns k0, R, A), weighted by 1/(w^2 m)
    wt = 1.0 / (w * w * mass)
    cols = np.stack([-Xb, -1j * w * Xb, Mb], axis=1) * wt[:, None]
    y = -mass * w * w * Xb * wt
    A = np.concatenate([cols.real, cols.imag])
    b = np.concatenate([y.real, y.imag])
    (k0, r, area), *_ = np.linalg.lstsq(A, b, rcond=None)
    return {"k0_n_per_m": k0, "r_ns_per_m": r, "f0_hz": np.sqrt(max(k0, 0) / mass) / (2 * np.pi),
            "force_per_mic_v_n_per_v": area}


def band_limited(sig, fs, stop_hz, order, decim):
    n = next_pow2(len(sig) + 64)
    S = np.fft.rfft(sig, n)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    pass_hz = 2 * stop_hz / 3
    taper = np.clip((stop_hz - f) / (stop_hz - pass_hz), 0.0, 1.0)
    S = S * (0.5 - 0.5 * np.cos(np.pi * taper)) * (2j * np.pi * f) ** order
    return np.fft.irfft(S, n)[:len(sig):decim]


def stiffness(main, fs, mass, ch):
    stop = min(1200.0, 0.4 * fs)
    decim = max(1, int(fs / (4 * stop)))
    x = band_limited(main[ch["displacement"]], fs, stop, 0, decim)
    v = band_limited(main[ch["displacement"]], fs, stop, 1, decim)
    a = band_limited(main[ch["displacement"]], fs, stop, 2, decim)
    mic = band_limited(main[ch["microphone"]], fs, stop, 0, decim)
    env = np.abs(x) > 0.1 * np.max(np.abs(x))
    idx = np.flatnonzero(env)
    s0, s1 = idx[0], idx[-1] + 1
    x, v, a, mic = x[s0:s1], v[s0:s1], a[s0:s1], mic[s0:s1]
    xs = np.max(np.abs(x))
    y = mass * a
    best = None
    for order in range(1, 9):
        cols = [-(x / xs) ** (i + 1) for i in range(order + 1)] + [-v, mic]
        A = np.stack(cols, axis=1)
        coef, res, *_ = np.linalg.lstsq(A, y, rcond=None)
        rss = float(res[0]) if len(res) else float(np.sum((A @ coef - y) ** 2))
        bic = len(y) * np.log(rss / len(y)) + A.shape[1] * np.log(len(y))
        if best is None or bic < best[0]:
            best = (bic, order, coef)
    _, order, coef = best
    k = [coef[i] / xs ** (i + 1) for i in range(order + 1)]
    return {"order": order, "coefficients_n_per_m_pow_i_plus_1": k, "r_ns_per_m": coef[order + 1],
            "force_per_mic_v_n_per_v": coef[order + 2], "valid_range_m": [float(x.min()), float(x.max())]}


def main(d):
    meta = json.load(open(f"{d}/meta.json"))
    mass = meta["moving_mass_kg"]
    ch = {"displacement": 0, "microphone": 1, **meta.get("channels", {})}
    ch = {k: v for k, v in ch.items() if isinstance(v, int)}
    fs, pre = read_wav_f32(f"{d}/pre.wav")
    _, main_ = read_wav_f32(f"{d}/main.wav")
    ss = small_signal(pre, fs, mass, ch)
    st = stiffness(main_, fs, mass, ch)
    print(json.dumps({"small_signal": ss, "stiffness": st}, default=float, indent=1))


if __name__ == "__main__":
    main(sys.argv[1])
