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
N_LOOP = 19
MAX_ORDER = 4  # largest relative degree (position task)

# --- Controller row (one per scenario) --------------------------------------
C_ORDER = 0  # relative degree m: 3 velocity, 4 position
C_N = 1  # CLF power factor n (even integer >= 2)
C_SIGMA = 2  # CLF scale sigma [unit of s]
C_SMOOTH = 3  # sign(s) smoothing width w [unit of s]; 0 = plain law
C_LAM0 = 4  # combined-error coefficients lambda_0..lambda_2
C_LAM1 = 5
C_LAM2 = 6
C_ULIM = 7  # current limit [mA]; inf = unlimited
C_SEED = 8  # noise seed (integer stored as float)
C_NOISE_THETA = 9  # measurement noise std per plant state, in its unit
C_NOISE_OMEGA = 10
C_NOISE_PL = 11
C_NOISE_AV = 12
C_OMEGA_MAX = 13  # divergence bound on |x2| [rad/s]
C_P_BOUND = 14  # divergence bound on |x3| as a multiple of P_s
C_BASE = 15  # gain on the Sontag current: 1 = base law + residual, 0 = residual only (pure RL)
C_EST = 16  # output-derivative estimator and filter scheme of the reference model: one of EST_* below
C_LAW = 17  # the CLF law: one of LAW_* below
C_LAYER_GAIN = 18  # adaptive boundary layer: w_eff = max(w, gain * noise std of s); 0 = the fixed width w
C_BUMPLESS = 19  # 1: the reference model starts at the measured output (bumpless start); 0: at r(0)
C_REF_ACCEL = 20  # acceleration bound of the reference shaper [rad/s^2] (position task); 0 = r drives the model
C_PDOMAIN = 21  # the model is evaluated at |x3| <= C_PDOMAIN * P_s (of the model); inf = at the measured x3 as is
N_CTRL = 22

# --- Estimators (Scenario.estimator; docs/MODEL.md, "Digital filters" and "Estimators") ------------------
# The first three are the paper's state-variable filter (SVF) in three schemes, the reference model in the same one;
# the others form the derivatives without differentiating the output, their reference model runs "foh".
EST_FOH = 0  # "foh": SVF, first-order hold with a direct feed-through term, O(h^2) to the analog filter
EST_ZOH = 1  # "zoh": SVF, zero-order hold, top derivative from the current sample (wave 1's scheme; biased by O(h))
EST_ANALOG = 2  # "analog": the continuous SVF integrated with the plant by its RK4 (the reference)
EST_STATE = 3  # "state": y^(i) = L_f^i h(x_meas), the model's Lie derivatives of the measured state
EST_ESO = 4  # "eso": extended-state observer of the velocity and a lumped disturbance acceleration
ESTIMATORS = ("foh", "zoh", "analog", "state", "eso")  # name -> code is the index
SVF_ESTIMATORS = ("foh", "zoh", "analog")

# --- CLF laws (Scenario.law; docs/MODEL.md, "Laws") --------------------------------------------------
LAW_SONTAG = 0  # "sontag": Sontag's universal formula (the paper's)
LAW_LIN_SONTAG = 1  # "lin-sontag": Lin & Sontag's universal formula for |u| <= the current limit
LAWS = ("sontag", "lin-sontag")  # name -> code is the index

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
R_KIND = 0  # one of REF_* below
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
REF_SINE = 0
REF_STEP = 1
REF_CHIRP = 2
REF_MULTISINE = 3
REF_TABLE = 4  # samples (t_i, r_i) interpolated linearly, held outside [t_0, t_last]; past the fixed row:
R_TAB_N = 4  # number of samples n (a table uses no other slot but R_KIND and R_OFFSET)
R_TAB0 = N_REF  # t_0..t_(n-1) [s] start here, then r_0..r_(n-1): a table row is N_REF + 2n long

# --- Friction events: rows of (amplitude [N*m], start [s], end [s]) --------
F_AMP = 0
F_START = 1
F_END = 2

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
I_UBASE = 19  # Sontag current [mA]
I_URES = 20  # residual current [mA]
I_UCMD = 21  # commanded current u_base + u_res [mA]
I_UAPP = 22  # applied (limited) current [mA]
I_SAT = 23  # 1 if the limit was active
I_TF = 24  # friction torque at the sample [N*m]
I_FRIC_ON = 25  # 1 if a friction event is active
I_XM = 26  # measured plant states x1..x4 (with noise), 4 slots
I_QUIET = 30  # 1 if the sample counts for the quiet RMSE: past the start-up, away from friction and its settling
I_AM = 31  # model acceleration (d_m x3 - B x2)/J of the measured state [rad/s^2], the observer's input
I_W = 32  # boundary-layer width in use (the fixed w, or the adaptive one) [unit of s]
I_E_TRUE = 33  # true tracking error y - y_d (the plant's output, no sensor noise): what the metrics *_true use
I_RM = 34  # the reference model's input: r, or the shaped reference p (C_REF_ACCEL > 0)
I_E_R = 35  # true output minus the raw reference r (no reference model): what the metric rmse_r uses
I_WIN = 36  # the metric window of the sample: one of WIN_* below (every sample is in exactly one)
N_INFO = 37
QUIET_STARTUP = 0.2  # [s] the start-up window (t < this), excluded from the quiet RMSE and the tracking class
QUIET_GUARD = 0.2  # [s] settling time after each friction event ends, counted with the event's window
# Metric windows (ehss_gym.core.metrics): the start-up t < QUIET_STARTUP; past it, a disturbance window is
# [start, end + QUIET_GUARD) of any friction event of the scenario, whatever its amplitude (an event of amplitude 0
# keeps its window, so a scenario with its friction removed is measured on the same samples); tracking is the rest.
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
M_SUM_E2_QUIET = 19  # sum e^2 over the quiet samples (I_QUIET)
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
N_METRICS = 42
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
N_LOG = 30

# --- The envs' per-lane buffers (ehss_gym.envs.lanes) ---------------------------------------------
# Per-agent-step statistics and reward-weight slots of the kernel.
S_SUM_E2, S_N, S_SAT, S_TV0 = 0, 1, 2, 3  # S_TV0: the lane's accumulated control TV when the step began
S_UMIN, S_UMAX = 4, 5  # smallest and largest applied current [mA] over the step's control periods
N_STATS = 6
W_TRACK, W_EFFORT, W_RATE, W_TV, W_TVU, W_DIV, W_INV_E2, W_INV_SCALE = range(8)
N_WEIGHTS = 8

# Per-lane float64 buffer F (B, N_F): column blocks, so one kernel argument carries them all (numba's
# dispatch costs ~0.1 us per array argument, a large share of a 15 us step).
N_PARAM = 14  # len(PlantParams._fields): checked by ehss_gym.core.params
F_Z = 0  # loop state (N_LOOP)
F_PLANT = F_Z + N_LOOP  # true plant parameters
F_MODEL = F_PLANT + N_PARAM  # controller's model parameters
F_CTRL = F_MODEL + N_PARAM  # controller row (N_CTRL)
F_REF = F_CTRL + N_CTRL  # reference spec (N_REF)
F_INFO = F_REF + N_REF  # control-step info (N_INFO), scratch alternating with F_INFO_OK
F_INFO_OK = F_INFO + N_INFO  # last finite control-step info
F_PEEK = F_INFO_OK + N_INFO  # the controller's view at the next sample
F_PEEKZ = F_PEEK + N_INFO  # loop state after that sample's filter advance (N_LOOP; must follow F_PEEK)
F_ACC = F_PEEKZ + N_LOOP  # metrics accumulator (N_METRICS)
F_ZPREV = F_ACC + N_METRICS  # loop state at the last sample (scratch of lanes_period)
F_STATS = F_ZPREV + N_LOOP  # per-agent-step statistics (N_STATS)
F_URES = F_STATS + N_STATS  # residual current [mA]
F_REW = F_URES + 1  # reward of the last step
F_APREV = F_REW + 1  # previous normalised action
N_F = F_APREV + 1
# Per-lane int64 buffer: step index k, agent steps taken, group id (scratch).
IB_K, IB_NSTEP, IB_GID = 0, 1, 2
N_IB = 3
# Per-lane bool buffer: running (not diverged, not held), group member (scratch), F_PEEK/F_PEEKZ hold
# the controller's view at the lane's next period (set by the look-ahead, cleared when used or reloaded).
BB_RUN, BB_ACT, BB_PRE = 0, 1, 2
N_BB = 3
# Observation layout rows (3, D): info index, scale, flags (1 = symlog squash, 2 = from the last period).
LAY_SRC, LAY_SCALE, LAY_FLAGS = 0, 1, 2
FLAG_SQUASH, FLAG_LAST = 1, 2
