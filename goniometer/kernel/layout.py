"""The lane state and the stack table of the lane kernel (``docs/kernel.md``).

Lane state: one flat float64 array ``S`` of :data:`N_FIELDS` rows of :data:`LANES` lanes, field
``f`` of lane ``i`` at ``S[f * LANES + i]``; integers are stored exactly as doubles, path keys and
generator states as the bits of doubles. The lane count is a compile-time constant: the rows are
then a constant distance apart, which is what lets LLVM prove the lanes of the event loop
independent (separate arrays would need a run-time alias check per pair).
"""

from __future__ import annotations

import numba
import numpy as np

#: paths advanced in lock-step by one chunk's kernel
LANES = 64

# ---- outputs of a chunk
# rows of the per-chunk energy array
E_REFLECTED = 0
E_TRANSMITTED = 1
E_ABSORBED = 2
E_MASKING = 3
#: reflected weight of paths that never had an event at the base (the bottom layer)
E_REFLECTED_WITHOUT_BASE = 4
E_ROULETTE = 5
E_CAPPED = 6
N_ENERGY = 7
#: rows with a per-path second moment (for standard errors)
N_ENERGY_SQ = 5
# columns of the per-chunk counters
C_CAPPED = 0
C_EVENTS = 1
N_COUNTS = 2

#: ``param`` of the kernels (:func:`goniometer.kernel.tracer.prepare`) for a tabulation
#: (``docs/tabulated-format.md``): every path draws its own incident direction (cosine-weighted), and a
#: reflected exit is recorded per path as its MERL cell (:func:`goniometer.grids.halfdiff.cell_of`) and
#: weight instead of in a slice histogram
P_TABULATE = 2


# ---- fields; those up to N_RESET - 1 are set to a new path's values when a lane takes one
F_DX, F_DY, F_DZ = 0, 1, 2          # direction of travel (world frame)
F_W0, F_W1, F_W2 = 3, 4, 5          # path weight per channel
F_AB0, F_AB1, F_AB2 = 6, 7, 8       # weight lost to absorption so far
F_MK0, F_MK1, F_MK2 = 9, 10, 11     # weight lost to masking so far
F_REG = 12                          # region the path is in (0 air .. n_if)
F_EV = 13                           # events so far
F_ORDER = 14                        # events at the top interface (the bounce order)
F_CTR = 15                          # next counter-based draw of the path
F_BASED = 16                        # 1 once the path had an event at the base
F_Q0, F_Q1, F_Q2 = 17, 18, 19       # spectral-MIS technique shares of the path
F_HPOS = 20                         # height in a scattering region (< 0: at its boundary)
F_SEEDED = 21                       # 1 once the path's xoshiro state (F_X0..) is seeded
N_RESET = 22
F_STATUS = 22                       # ST_*
F_KEY = 23                          # path key (bits)
F_PATH = 24                         # index of the path in its chunk (lane i: i, i + LANES, ...)
F_LX, F_LY, F_LZ = 25, 26, 27       # the path's light direction (a tabulation draws one per path)
F_X0 = 28                           # xoshiro256** state, F_X0 .. F_X0 + 3 (bits)
# a microsurface walk the vectorised event began and a per-lane step continues: interface + 1
# (0: none), the ray's direction of travel and height CDF in the walk's frame, 1 if it is on the
# far side of the microsurface (goniometer.kernel.steps.continue_walk)
F_WK = 32
F_WVX, F_WVY, F_WVZ = 33, 34, 35
F_WC = 36
F_WIN = 37
#: 1 when the path's last walk on a multiple-scattering top interface made more than one bounce
#: (its order-1 exit is then not the closed form of goniometer.run.first_order)
F_MULTI = 38
# ---- per-lane sums over the lane's ended paths (summed over lanes at the end of the chunk)
A_RE = 39       # reflected weight (3 channels), then its squares at A_RE + 3
A_RB = 45       # reflected weight of paths that never reached the base, squares at + 3
A_TR = 51       # transmitted weight, squares at + 3
A_AB = 57       # absorbed, squares at + 3
A_MK = 63       # masking loss, squares at + 3
A_RL = 69       # roulette's net change of the weight (3)
A_CP = 72       # capped weight (3)
A_NCAP = 75     # capped paths
A_NEV = 76      # events
N_FIELDS = 77
# ---- a polarized run's fields after those (its state array has N_FIELDS_POLARIZED rows): the path's
# state of goniometer.kernel.polarized per lane, element e (row-major 4 x 4) of channel c's Mueller
# matrix at row F_MUELLER + 16 c + e, the Stokes frame's x axis at F_FRAME .. F_FRAME + 2
F_MUELLER = 77
F_FRAME = 125
# and 1 where renew gave the lane a new path at this step (whose matrices stage B reads as the identity)
F_PNEW = 128
#: and the rows where stage B leaves a polarized lane's event for the pass over its matrices
#: (goniometer.kernel.event.mueller_pass): per channel c the six numbers (A0, A1, B, C, S, F) of the
#: event's matrix at F_EVENT + 6 c (goniometer.kernel.polarized.lane_coefficients), the traversal's
#: factors at F_EVENT + 18 + c; the frame's rotation (cos 2 theta, sin 2 theta), the masking factor,
#: roulette's boost, 1 where the lane took the event, 1 where its path is new, at F_EVENT + 21 ..
F_EVENT = 129
N_EVENT = 27
N_FIELDS_POLARIZED = 156

# ---- lane status after a step
# (an ended path -- ST_REFLECTED .. ST_CAPPED -- is booked, and its lane given the next path, at the
# start of the next vectorised step)
ST_ALIVE = 0        # travelling; its next action is the vectorised event
ST_SCALAR = 1       # travelling; its next action is a per-lane step (a walk's continuation)
ST_REFLECTED = 2    # left the stack upward (BRDF)
ST_TRANSMITTED = 3  # left a transmitting stack downward (BTDF)
ST_DEAD = 4         # ended: masking loss (weight 0) or killed by roulette (weight kept for booking)
ST_CAPPED = 5       # stopped by the event cap (weight kept for booking)
ST_DONE = 6         # the lane has no path left in the chunk

# ---- the stack table the event reads per lane (copied to the stack of the event loop)
#: per interface k, at k * IF_STRIDE: alpha_x, alpha_y, cos and sin of the tangent-frame rotation,
#: relative index going down and up, 1.0 where index-matched (optically absent), 1.0 where
#: multiple-scattering
IF_STRIDE = 8
T_AX, T_AY, T_RC, T_RS, T_ETA_DN, T_ETA_UP, T_MATCHED, T_MS = range(8)
#: per region r, at region_offset + r * RG_STRIDE: the optical depths (Beer-Lambert, or a scattering
#: region's extinction), 1.0 where the region scatters, and for a scattering region the inverse
#: depths (0 where zero), the single-scattering albedos, the Henyey-Greenstein g and 1.0 where the
#: extinction is chromatic (spectral MIS)
RG_STRIDE = 12
T_TAU0, T_TAU1, T_TAU2, T_SCAT, T_IEXT0, T_IEXT1, T_IEXT2, T_ALB0, T_ALB1, T_ALB2, T_G, T_CHROM = range(12)

#: a stack with a thin film (the film variant, ``docs/kernel.md``) appends, at
#: ``off + (n_if + 1) * RG_STRIDE``, per interface k ``FILM_COLS`` columns: the packed film of
#: interface k (:data:`goniometer.kernel.packing.FILM_COLS`, columns ``FL_*``); a stack without films has
#: no such block (its table is the same as before films existed)

# tau_mode per region (as the steps read it): 0 clear, 1 achromatic absorption, 2 chromatic;
# TAU_SCATTER (+ 1 chromatic extinction) a scattering medium
TAU_SCATTER = 3


@numba.njit(cache=True, error_model='numpy')
def tau_modes(region_tau: np.ndarray, region_albedo: np.ndarray) -> np.ndarray:
    """Per region: 0 clear, 1 achromatic absorption, 2 chromatic; a scattering medium (albedo > 0
    where tau > 0): TAU_SCATTER with achromatic extinction, TAU_SCATTER + 1 chromatic."""
    n = region_tau.shape[0]
    mode = np.zeros(n, dtype=np.int64)
    for r in range(n):
        t0 = region_tau[r, 0]
        if t0 > 0.0 or region_tau[r, 1] > 0.0 or region_tau[r, 2] > 0.0:
            achromatic = region_tau[r, 1] == t0 and region_tau[r, 2] == t0
            mode[r] = 1 if achromatic else 2
            for c in range(3):
                if region_albedo[r, c] > 0.0 and region_tau[r, c] > 0.0:
                    mode[r] = TAU_SCATTER if achromatic else TAU_SCATTER + 1
    return mode


@numba.njit(cache=True, error_model='numpy')
def relative_indices(region_eta: np.ndarray):
    """Per interface k: the relative index going down (``n_{k+1} / n_k``) and up (its inverse);
    ones for a stack without interfaces."""
    n_if = region_eta.shape[0] - 1
    eta_dn = np.ones(max(n_if, 1))
    eta_up = np.ones(max(n_if, 1))
    for k in range(n_if):
        eta_dn[k] = region_eta[k + 1] / region_eta[k]
        eta_up[k] = 1.0 / eta_dn[k]
    return eta_dn, eta_up


@numba.njit(cache=True, error_model='numpy')
def stack_table(if_alpha, if_rot, if_ms, eta_dn, eta_up, region_tau, region_albedo, region_g, tau_mode, n_if,
                conductor_base, if_film, has_film):
    """The flat table of the event (layout above) and the offset of its region part; with
    ``has_film`` the films' block after the regions (an interface with a film is not
    index-matched: the film reflects)."""
    n_k = max(n_if, 1)
    off = n_k * IF_STRIDE
    foff = off + (n_if + 1) * RG_STRIDE
    n_film = if_film.shape[1]
    t = np.zeros(foff + (n_k * n_film if has_film else 0))
    for k in range(n_k):
        b = k * IF_STRIDE
        t[b + T_AX] = if_alpha[k, 0]
        t[b + T_AY] = if_alpha[k, 1]
        t[b + T_RC] = if_rot[k, 0]
        t[b + T_RS] = if_rot[k, 1]
        t[b + T_ETA_DN] = eta_dn[k]
        t[b + T_ETA_UP] = eta_up[k]
        is_cond = conductor_base and k == n_if - 1
        filmed = has_film and if_film[k, 0] != 0.0
        t[b + T_MATCHED] = 1.0 if (k < n_if and not is_cond and eta_dn[k] == 1.0 and not filmed) else 0.0
        t[b + T_MS] = 1.0 if (k < n_if and if_ms[k] and t[b + T_MATCHED] == 0.0) else 0.0
    for r in range(n_if + 1):
        b = off + r * RG_STRIDE
        t[b + T_TAU0] = region_tau[r, 0]
        t[b + T_TAU1] = region_tau[r, 1]
        t[b + T_TAU2] = region_tau[r, 2]
        if tau_mode[r] >= TAU_SCATTER:
            t[b + T_SCAT] = 1.0
            t[b + T_CHROM] = 1.0 if tau_mode[r] > TAU_SCATTER else 0.0
            t[b + T_G] = region_g[r]
            for c in range(3):
                t[b + T_IEXT0 + c] = 1.0 / region_tau[r, c] if region_tau[r, c] > 0.0 else 0.0
                t[b + T_ALB0 + c] = region_albedo[r, c]
    if has_film:
        for k in range(n_k):
            for j in range(n_film):
                t[foff + k * n_film + j] = if_film[k, j]
    return t, off
