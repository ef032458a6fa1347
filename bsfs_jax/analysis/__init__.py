"""Nonlinear-dynamics analysis, generic over any forced vector field f(t, y, args).

- sweeps: `SweepProblem`, `SweepConfig`, `sweep`, `SweepResult`, `load_sweep`,
  `bsfs_problem` (the ball screw), `detect_jumps`;
- analyses: `stroboscopic`, `amplitude_spectrum`, `largest_lyapunov`, `classify_motion`.
"""

from ._atlas import atlas as atlas
from ._atlas_result import Atlas as Atlas
from ._atlas_result import load_atlas as load_atlas
from ._bsfs import bsfs_problem as bsfs_problem
from ._bsfs import parameter_unit as parameter_unit
from ._classify import ClassifierSettings as ClassifierSettings
from ._classify import Motion as Motion
from ._classify import classify_motion as classify_motion
from ._classify import strobe_period as strobe_period
from ._jumps import locate_jump_folds as locate_jump_folds
from ._lyapunov import LyapunovResult as LyapunovResult
from ._lyapunov import TangentField as TangentField
from ._lyapunov import largest_lyapunov as largest_lyapunov
from ._poincare import poincare_points as poincare_points
from ._poincare import stroboscopic as stroboscopic
from ._spectrum import amplitude_spectrum as amplitude_spectrum
from ._spectrum import line_fraction as line_fraction
from ._sweep import sweep as sweep
from ._sweep_problem import SweepConfig as SweepConfig
from ._sweep_problem import SweepProblem as SweepProblem
from ._sweep_result import Jump as Jump
from ._sweep_result import SweepResult as SweepResult
from ._sweep_result import detect_jumps as detect_jumps
from ._sweep_result import load_sweep as load_sweep
from ._verify import minimum_transient as minimum_transient
from ._verify import slowest_decay_rate as slowest_decay_rate
from ._verify import verify_points as verify_points
from ._verify import verify_sweep as verify_sweep
from ._verify_settings import VERDICT_FIELDS as VERDICT_FIELDS
from ._verify_settings import VerifySettings as VerifySettings
