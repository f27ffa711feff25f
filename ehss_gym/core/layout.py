"""Every index into a flat float64 array, named once and used everywhere.

The compiled kernels work on flat arrays; these module-level integers are
compile-time constants to numba, so naming them costs nothing at run time.
"""

# --- Loop state: plant, reference model, output-derivative estimator -------
X_THETA = 0  # x1, angular position [rad]
X_OMEGA = 1  # x2, angular velocity [rad/s]
X_PL = 2  # x3, load pressure difference [Pa]
X_AV = 3  # x4, servo-valve opening area [m^2]
N_PLANT = 4
Z_REF = 4  # reference-model state y_d, y_d', ... (up to 4 slots)
Z_EST = 8  # estimator state y_e, y_e', ... (up to 3 slots)
Z_OBS = 11  # extended-state observer ("eso"): velocity and lumped disturbance acceleration (FOH form, 2 slots)
Z_NOISE = 13  # noise estimate of the adaptive boundary layer: last s, running mean of (s_k - s_{k-1})^2
Z_SHAPE = 15  # reference shaper (position task): shaped reference p, its rate, the last r and its last rate
Z_DOB = 19  # disturbance observer: d_hat [unit of s / s], the last s, the last prediction psi + G u_app of s'
# The effects the law's model leaves out (ehss_gym.core.unmodelled): the valve's play (hysteresis) operator output
# [mA], then the sensor delay line, MAX_DELAY samples of the N_PLANT measured states (slot j holds x1..x4 at j * 4).
Z_PLAY = 22
Z_DELAY = 23
MAX_DELAY = 8  # largest sensor delay [control samples]
MAX_ORDER = 4  # largest relative degree (position task)
# The compensators of those effects (loop settings, off by default; ehss_gym.core.compensators): the valve inverse's
# model of the play operator's output [mA], then the reference delay's ring of the reference model's outputs y_d,
# y_d', ..., y_d^(m) at the last REF_RING samples (slot j holds them at Z_REF_RING + j * N_YD).
Z_VINV = Z_DELAY + N_PLANT * MAX_DELAY
Z_REF_RING = Z_VINV + 1
N_YD = MAX_ORDER + 1  # y_d and its derivatives up to the largest relative degree
REF_RING = MAX_DELAY + 2  # samples kept: a delay of up to MAX_DELAY samples, interpolated with the sample before
# The law's reference shift (ehss_gym.core.controller.reference_shift): the state of the reference model's copy that
# the shift delta drives (up to 4 slots, the reference model's digital form)
Z_SHIFT = Z_REF_RING + REF_RING * N_YD
N_LOOP = Z_SHIFT + MAX_ORDER

# --- Plant parameters: PlantParams.as_array() --------------------------------
N_PARAM = 14  # len(PlantParams._fields): checked by ehss_gym.core.params

# The controller row (one per scenario: the loop settings as the kernels read them) is laid out next to the
# settings it encodes: C_* in ehss_gym.core.settings.

# --- Filter block (one per scenario, shape (N_FB, MAX_ORDER, MAX_ORDER)): discretised filters ------
# Digital form of each filter (state w, input v held or interpolated, see filters.py):
#   state estimate at the sample   z_k = w_k + D v_k
#   top derivative                 z^(m)_k = c_0 v_k - sum_i c_i z_k[i]
#   advance over the period        w_{k+1} = Phi w_k + E v_k
FB_PHI_REF = 0  # reference-model Phi (m x m)
FB_PHI_EST = 1  # estimator Phi ((m-1) x (m-1))
FB_VEC = 2  # rows of vectors:
FBV_C_REF, FBV_C_EST, FBV_E_REF, FBV_E_EST = 0, 1, 2, 3  # coefficients c and input vectors E, in block FB_VEC
FB_VEC2 = 3  # more rows:
FBV_D_REF, FBV_D_EST = 0, 1  # feed-through vectors D, in block FB_VEC2
# The extended-state observer ("eso"), the same digital form with two states (velocity, disturbance) and two
# inputs v = (model acceleration a_m, measured velocity): w_{k+1} = Phi w_k + E v_k, state z_k = w_k + D v_k.
FB_PHI_OBS = 4  # Phi (2 x 2)
FB_E_OBS = 5  # E (2 states x 2 inputs)
FB_D_OBS = 6  # D (2 states x 2 inputs)
N_FB = 7

# --- Reference signal spec row ------------------------------------------------
R_KIND = 0  # the family's code: its index in ehss_gym.core.registry.REFERENCE_FAMILIES
R_OFFSET = 1  # constant offset [output unit]
R_T0 = 2  # step time / chirp start [s]
R_T1 = 3  # chirp end [s]
R_A1 = 4  # first component: amplitude, angular frequency [rad/s], phase [rad]
R_W1 = 5
R_P1 = 6
R_W_END = 7  # chirp end frequency [rad/s]
R_MS0 = 8  # multi-sine components start here, (A, w, phi) each
MAX_SINES = 4
N_REF = R_MS0 + 3 * MAX_SINES
# A sampled ("table") reference: samples (t_i, r_i) interpolated linearly, held outside [t_0, t_last]. Past the
# fixed row:
R_TAB_N = 4  # number of samples n (a table uses no other slot but R_KIND and R_OFFSET)
R_TAB0 = N_REF  # t_0..t_(n-1) [s] start here, then r_0..r_(n-1): a table row is N_REF + 2n long

# --- Friction events: rows of (amplitude [N*m], start [s], end [s]) --------
EV_AMP = 0
EV_START = 1
EV_END = 2

# --- Per-control-step info (what the law saw and did) -----------------------
I_T = 0  # sample time [s]
I_R = 1  # reference input r
I_YD = 2  # y_d, y_d', ..., y_d^(m)  (5 slots)
I_YE = 7  # y_meas, y_e', ..., y_e^(m-1) (4 slots)
I_E = 11  # e, e', ..., e^(m-1) (4 slots)
I_S = 15  # combined error s
I_V = 16  # V = (s/sigma)^n / n
I_PSI = 17  # psi, the drift of s
I_G = 18  # input gain of s [unit of s per s per mA]
I_UBASE = 19  # the base current [mA]: the law's, plus the disturbance observer's (I_UDOB)
I_URES = 20  # residual current [mA]
I_UCMD = 21  # commanded current u_base + u_res [mA]
I_UAPP = 22  # applied (limited) current [mA]
I_SAT = 23  # 1 if the limit was active
I_TF = 24  # the plant's friction torque at the sample [N*m] (recorded by the loop; the controller does not know it)
I_XM = 25  # measured plant states x1..x4 (with noise), 4 slots
I_AM = 29  # model acceleration (d_m x3 - B x2)/J of the measured state [rad/s^2], the observer's input
I_W = 30  # boundary-layer width in use (the fixed w, or the adaptive one) [unit of s]
I_E_TRUE = 31  # true tracking error y - y_d (the plant's output, no sensor noise): what the metrics *_true use
I_RM = 32  # the reference model's input: r, or the shaped reference p (C_REF_ACCEL > 0)
I_E_R = 33  # true output minus the raw reference r (no reference model): what the metric rmse_r uses
I_DHAT = 34  # the disturbance observer's estimate d_hat of the lumped disturbance of s' [unit of s / s]; 0 if off
I_UDOB = 35  # the observer's current -d_hat/G, clipped to the limit [mA] (part of I_UBASE); 0 if off
I_SHIFT = 36  # the law's reference shift Delta at the sample [output unit] (its y_d is I_YD + Delta); 0 if off
N_INFO = 37
# A sample is quiet (it counts for the quiet RMSE) past the start-up and neither in a friction event nor within
# QUIET_GUARD after one ends (ehss_gym.core.metrics.accumulate classifies it, and its metric window below).
QUIET_STARTUP = 0.2  # [s] the start-up window (t < this), excluded from the quiet RMSE and the tracking class
QUIET_GUARD = 0.2  # [s] settling time after each friction event ends, counted with the event's window
# Metric windows (ehss_gym.core.metrics): the start-up t < QUIET_STARTUP; past it, a disturbance window is
# [start, end + QUIET_GUARD) of any friction event of the scenario, whatever its amplitude (an event of amplitude 0
# keeps its window, so a scenario with its friction removed is measured on the same samples); tracking is the rest.
# Every sample is in exactly one.
WIN_STARTUP = 0
WIN_DISTURBANCE = 1
WIN_TRACKING = 2

# --- Online metrics accumulator -------------------------------------------
M_STEPS = 0  # control steps taken
M_SUM_E2 = 1  # sum e^2
M_SUM_ABS_E = 2  # sum |e| * h  (IAE)
M_SUM_T_ABS_E = 3  # sum t*|e| * h  (ITAE)
M_MAX_E = 4
M_MAX_E_FRIC = 5  # max |e| while a friction event is active
M_STEPS_FRIC = 6
M_TV_U = 7  # sum |u_k - u_{k-1}| of the applied current [mA]
M_PEAK_UCMD = 8
M_PEAK_UAPP = 9
M_SUM_U2 = 10
M_N_SAT = 11
M_N_VDEC = 12  # steps with V_k < V_{k-1}
M_LAST_U = 13
M_LAST_V = 14
M_DIVERGED = 15  # 0, or a DIV_* code
M_T_DIVERGED = 16  # time of divergence [s], nan-free: -1 if none
M_SUM_E2_NOFRIC = 17
M_STEPS_NOFRIC = 18
M_SUM_E2_QUIET = 19  # sum e^2 over the quiet samples
M_STEPS_QUIET = 20
M_SUM_E2_SETTLED = 21  # sum e^2 over the steps past the start-up (t >= QUIET_STARTUP) with no friction event
M_STEPS_SETTLED = 22
# Lost-track detection (ehss_gym.core.metrics): its bound is a parameter of the accumulator, set when a run is loaded
M_LOST_BOUND = 23  # bound on the windowed RMS of e [output unit]; inf = detection off
M_LOST_EMA = 24  # exponential moving mean of e^2 over LOST_TRACK_WINDOW, from t = QUIET_STARTUP on
M_LOST = 25  # 1 once the windowed RMS of e has exceeded the bound
M_T_LOST = 26  # time it first did [s]; -1 if never
M_SUM_E2_TRUE = 27  # sum of the true error's squares (I_E_TRUE): the sensor noise left out
M_SUM_E2_QUIET_TRUE = 28  # the same over the quiet samples
M_MAX_E_FRIC_TRUE = 29  # max |true error| while a friction event is active
M_SUM_ER2 = 30  # sum of (y - r)^2, the true output against the raw reference (I_E_R)
M_SUM_ABS_ER = 31  # sum |y - r| h (I_E_R): the IAE against the raw reference
# The metric classes over the windows (I_WIN), on the true error e_t (I_E_TRUE):
# steps, sum e_t^2, sum |e_t| h, max |e_t|
M_SU_STEPS = 32  # start-up window
M_SU_SUM_E2 = 33
M_SU_SUM_ABS = 34
M_SU_MAX = 35
M_DST_STEPS = 36  # disturbance windows
M_DST_SUM_ABS = 37
M_DST_MAX = 38
M_TRK_STEPS = 39  # tracking window
M_TRK_SUM_E2 = 40
M_TRK_SUM_ABS = 41
M_N_VMODEL_DEC = 42  # steps with the model's V' < 0 at the applied current (sign(s) (psi + G u_app) < 0), or s = 0
N_METRICS = 43
LOST_TRACK_WINDOW = 0.1  # [s] time constant of the windowed (exponential moving) RMS of e

DIV_NONE = 0
DIV_NONFINITE = 1
DIV_OMEGA = 2
DIV_PRESSURE = 3
DIV_CURRENT = 4
DIV_NAMES = ("none", "non-finite value", "velocity bound", "pressure bound", "non-finite current")

# --- Trajectory log columns --------------------------------------------------
L_T = 0
L_X = 1  # 4 plant states
L_R = 5
L_YD = 6  # y_d..y_d^(m) (5 slots)
L_YE = 11  # measured y and estimated derivatives (4 slots)
L_E = 15  # e .. e^(m-1) (4 slots)
L_S = 19
L_V = 20
L_UBASE = 21
L_URES = 22
L_UCMD = 23
L_UAPP = 24
L_TF = 25
L_UMIN = 26  # smallest applied current [mA] over the control periods the sample stands for (its log interval)
L_UMAX = 27  # largest
L_W = 28  # boundary-layer width in use
L_RM = 29  # the reference model's input (r, or the shaped reference)
L_DHAT = 30  # the disturbance observer's d_hat [unit of s / s]
L_UDOB = 31  # the observer's current [mA] (part of L_UBASE)
N_LOG = 32
