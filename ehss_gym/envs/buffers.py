"""Every index into the envs' per-lane buffers (:class:`ehss_gym.envs.lanes.Lanes`), named once.

The compiled step (:mod:`ehss_gym.envs.kernels`) reads these module-level integers as compile-time constants. The
blocks of the hot float buffer H hold the core's arrays (loop state, parameter rows, controller row, reference row,
info, metrics accumulator), laid out by :mod:`ehss_gym.core.layout` and :mod:`ehss_gym.core.settings`; the per-lane
buffer F holds the agent step's (statistics, residual, reward, the rewards' constants, memory, action).
"""

from ehss_gym.core.jit import jit_inline
from ehss_gym.core.layout import N_INFO, N_LOOP, N_METRICS, N_PARAM, N_REF
from ehss_gym.core.settings import N_CTRL

from .actions import ACTIONS

# Per-agent-step statistics and reward-weight slots of the kernel.
S_SUM_E2, S_N, S_SAT, S_TV0 = 0, 1, 2, 3  # S_TV0: the lane's accumulated control TV when the step began
S_UMIN, S_UMAX = 4, 5  # smallest and largest applied current [mA] over the step's control periods
S_SATF = 6  # share of the step's control periods at the current limit (0 if none ran)
# the metric-class sums of the accumulator when the step began (the class reward's differences): tracking sum e^2 and
# sum |e| h, disturbance sum |e| h and max |e|, sum u^2 (S_TV0 holds the TV)
S_TRK_E2, S_TRK_ABS, S_DST_ABS, S_DST_MAX, S_U2 = 7, 8, 9, 10, 11
# the accumulator's tracking and disturbance sample counts when the step began, and the step's largest |e_t| (the true
# error) over its control periods (the physical reward's)
S_TRK_N, S_DST_N, S_EMAX = 12, 13, 14
N_STATS = 15
W_TRACK, W_EFFORT, W_RATE, W_TV, W_TVU, W_DIV, W_INV_E2, W_INV_SCALE = range(8)
# the class reward's weight and the saturation weight; the memory filter: decay and gain per agent step, and its clip
W_CLASS, W_SAT, W_MEM_DECAY, W_MEM_GAIN, W_MEM_CLIP = range(8, 13)
# the action mode (ehss_gym.envs.actions): its code, 1 if its residual moves every control period, that update's two
# constants (ehss_gym.envs.actions.period_constants)
W_ACT_MODE, W_ACT_PERIOD, W_ACT_C1, W_ACT_C2 = range(13, 17)
W_PHYS = 17  # the physical reward's weight
N_WEIGHTS = 18
# The class reward's constants per lane (set at load from the base law's run of the episode), for its parts: tracking
# sum e^2, tracking sum |e| h, disturbance sum |e| h, disturbance max |e|, control TV, sum u^2 (N_PARTS). Block
# R_W: each part's weight (0 for a class the episode lacks); R_B: the base law's total of each part; R_K: the episode's
# agent steps.
R_TRK_E2, R_TRK_ABS, R_DST_ABS, R_DST_MAX, R_TV, R_U2 = range(6)
N_PARTS = 6
R_W = 0
R_B = N_PARTS
R_K = 2 * N_PARTS
N_RCLS = 2 * N_PARTS + 1
# The physical reward's constants per lane (set at load from the base law's run of the episode): its samples in the
# tracking and the disturbance windows and in all (the effort class's), its agent steps K, the number of classes it has,
# and each metric's scale, its physical floor plus the base law's level over the episode: the tracking window's mean
# e_t^2 [U^2] and mean |e_t| [U], the disturbance windows' peak |e_t| and mean |e_t| [U], the control TV rate [mA/s] and
# the mean u^2 [mA^2].
P_NTRK, P_NDST, P_N, P_K, P_NCLS, P_MS, P_MA, P_PK, P_DMA, P_TV, P_U2 = range(11)
N_RPHYS = 11
# The memory features per lane: the filtered error integral [output unit * s], the action of the step before last.
MEM_EINT, MEM_APREV2 = 0, 1
N_MEM = 2
# The agent's last action per lane in the action modes but "current" (their residual or law input is built from it;
# as many entries as the largest mode's action has), after the memory features in the lane's block of extras (the
# observation reads both from there).
N_ACT = max(row.dims + row.observer_dim for row in ACTIONS)

# The hot blocks, read or written every control period, in the flat float64 buffer H: block after block, each holding
# the rows of all B lanes, so a block is a (B, width) C-contiguous array (:func:`block`) whose lane rows numba knows
# to be contiguous (the loops over a lane's row, such as the divergence check over its loop state, vectorise; a column
# block of a (B, N) buffer has rows of a stride known only at run time: benchmarks/lane_stages.py measures both). One
# kernel argument carries them all (numba's dispatch costs ~0.1 us per array argument, a large share of a single env's
# step). The offsets count whole rows: block H_X starts at H[B * H_X] and spans its width times B doubles.
H_Z = 0  # loop state (N_LOOP)
H_PLANT = H_Z + N_LOOP  # true plant parameters
H_MODEL = H_PLANT + N_PARAM  # controller's model parameters
H_CTRL = H_MODEL + N_PARAM  # controller row (N_CTRL)
H_REF = H_CTRL + N_CTRL  # reference spec (N_REF)
H_INFO = H_REF + N_REF  # control-step info (N_INFO), scratch alternating with H_INFO_OK
H_INFO_OK = H_INFO + N_INFO  # last finite control-step info
# the controller's view at the next sample (N_INFO), then the loop state after that sample's filter advance (N_LOOP)
H_PEEK = H_INFO_OK + N_INFO
N_PEEK = N_INFO + N_LOOP
H_ACC = H_PEEK + N_PEEK  # metrics accumulator (N_METRICS)
H_ZPREV = H_ACC + N_METRICS  # loop state at the last sample (scratch of lanes_period)
N_H = H_ZPREV + N_LOOP
# (offset, width) of every hot block, in order
HOT_BLOCKS = ((H_Z, N_LOOP), (H_PLANT, N_PARAM), (H_MODEL, N_PARAM), (H_CTRL, N_CTRL), (H_REF, N_REF),
              (H_INFO, N_INFO), (H_INFO_OK, N_INFO), (H_PEEK, N_PEEK), (H_ACC, N_METRICS), (H_ZPREV, N_LOOP))


@jit_inline
def block(H, B, off, width):
    """Block ``off`` (H_*) of the flat buffer ``H`` of ``B`` lanes, ``width`` doubles per lane: a (B, width) view."""
    return H[B * off:B * (off + width)].reshape((B, width))


# Per-lane float64 buffer F (B, N_F): the blocks read or written once an agent step, as column blocks.
F_STATS = 0  # per-agent-step statistics (N_STATS)
F_URES = F_STATS + N_STATS  # residual current [mA]
F_REW = F_URES + 1  # reward of the last step
F_APREV = F_REW + 1  # previous normalised action
F_RCLS = F_APREV + 1  # the class reward's coefficients (N_RCLS; 0 = off)
F_MEM = F_RCLS + N_RCLS  # the memory features (N_MEM)
F_ACT = F_MEM + N_MEM  # the last action of a mode but "current" (N_ACT)
N_EXTRA = N_MEM + N_ACT  # the block of extras the observation reads (FLAG_MEM): memory features, then action
F_RPHYS = F_ACT + N_ACT  # the physical reward's constants (N_RPHYS; 0 = off)
N_F = F_RPHYS + N_RPHYS
# The int64 buffer IB (N_IB, B), a row per quantity (each contiguous over the lanes): step index k, agent steps taken,
# stepped in this call (0) or not (-1), the sample index of the control period under way (scratch: k plus the periods
# run so far in the step).
IB_K, IB_NSTEP, IB_GID, IB_KJ = 0, 1, 2, 3
N_IB = 4
# Per-lane bool buffer: running (not diverged, not held), group member (scratch), H_PEEK holds
# the controller's view at the lane's next period (set by the look-ahead, cleared when used or reloaded).
BB_RUN, BB_ACT, BB_PRE = 0, 1, 2
N_BB = 3
# Observation layout rows (3, D): info index, scale, flags (1 = symlog squash, 2 = from the last period, 4 = from the
# lane's block of extras F_MEM (memory features, action), the index then into it).
LAY_SRC, LAY_SCALE, LAY_FLAGS = 0, 1, 2
FLAG_SQUASH, FLAG_LAST, FLAG_MEM = 1, 2, 4
