"""Thermal plants: the hotends and beds the firmware heats, as named presets with their sources.

Two model families, one builder each:
- ``Lumped``: lumped thermal nodes with Marlin's MPC model as the template (Marlin 2.1.x Marlin/src/module/temperature.cpp MPC and Configuration.h):
  heater block and sensor, optionally a heater-cartridge node and radiation; states are absolute
  temperatures in degC.
- ``TransferFunction``: a seed paper's transfer function from heater input to temperature rise
  above ambient, with its dead time.

``make_plant(preset, **params)`` returns a ``Plant``: twin/linear.py's ``LinearPlant`` plus the
world's inputs (part fan, filament flow, ambient) and, for a radiating plant, relinearisation
between runs. In every preset the heater input u is 0..1 of full power; what full power is in the
source's own units is the preset's ``power_w`` or ``input_full_scale``. The numbers, their sources
and their check against real logs (``python -m tools.validation.plant_check``) are in docs/plants.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from twin.limits import PHYSICAL_RANGE_C, UserError, checked
from twin.linear import BLOCK, SENSOR, TICK_S, LinearPlant, Lti

PARAMETER_MAX = 1e9  # any plant parameter's magnitude: far beyond physics, far below float overflow

# Marlin 2.1 MPC defaults (Configuration.h, Marlin 2.1.x Marlin/src/module/temperature.cpp MPC and Configuration.h).
MPC_HEATER_POWER_W = 40.0
MPC_BLOCK_HEAT_CAPACITY_J_K = 16.7
MPC_SENSOR_RESPONSIVENESS_PER_S = 0.22
MPC_AMBIENT_XFER_W_K = 0.068  # fan off
MPC_AMBIENT_XFER_FAN255_W_K = 0.097  # fan at 255
MPC_FILAMENT_HEAT_CAPACITY_J_K_MM = 5.6e-3  # 1.75 mm PLA, per mm of filament

# Radiation (off unless a preset's emissivity is set).
STEFAN_BOLTZMANN_W_M2_K4 = 5.670374419e-8
KELVIN = 273.15
RADIATION_BIN_C = 0.5  # linearisation temperatures are multiples of this
V6_BLOCK_AREA_M2 = 2 * (16 * 20 + 16 * 11.5 + 20 * 11.5) * 1e-6  # E3D V6 block, 16 x 20 x 11.5 mm

# Condition keys: the part fan is an 8-bit PWM (M106 S0..255); flow is kept to 0.01 mm/s.
FAN_STEPS = 255
FLOW_DIGITS = 2

# hotend_cartridge: fitted to the onionheater no-fan pulse (hardware_logs README section B,
# heattest_200, first pulse 89.3..721.7 s, ambient 21.4 C) by `python -m tools.validation.plant_check --fit`.
# The log fixes ratios only, so the power is assumed and the cartridge's capacity estimated
# (refits with 1..8 J/K reach the same RMSE); block, contact, sensor and loss are fitted.
ONION_POWER_W = 40.0  # not stated by the author: Marlin's default
ONION_CARTRIDGE_HEAT_CAPACITY_J_K = 2.0  # 6 x 20 mm cartridge: ~4 g of sheath, MgO and coil x 0.5 J/(g K)
ONION_BLOCK_HEAT_CAPACITY_J_K = 14.38  # fitted
ONION_CARTRIDGE_XFER_W_K = 0.1632  # fitted
ONION_SENSOR_RESPONSIVENESS_PER_S = 0.09551  # fitted
ONION_AMBIENT_XFER_W_K = 0.08613  # fitted
# Then F on both fan runs at fan = 1, the rest fixed. It lies within the no-fan runs' own spread
# (0.086..0.102 W/K fitted run by run): these logs do not resolve a fan effect (docs/plants.md).
ONION_FAN_XFER_W_K = 0.0958  # fitted
# The same pulse fitted with a radiation-like loss at emissivity 1 over an effective area, chosen over
# the linear fit by AIC (-3555 against 2692; RMSE 0.43 against 1.89 C; the held-out sample_trace
# 1.53 against 2.07 C), `python -m tools.validation.plant_check --fit`. Parameters of
# hotend_cartridge, not its default: a radiating plant is relinearised between runs (the batch
# kernel's fast path needs a linear one). make_plant("hotend_cartridge", **ONION_RADIATING_PARAMS).
ONION_RADIATING_PARAMS = {
    "block_heat_capacity_j_k": 13.06, "cartridge_xfer_w_k": 0.1847, "sensor_responsiveness_per_s": 0.05787,
    "ambient_xfer_w_k": 0.04172, "fan_ambient_xfer_w_k": 0.05129,  # fitted; F on both fan runs at fan = 1
    "emissivity": 1.0, "radiating_area_m2": 0.004089,  # fitted area: 2.8 V6 blocks (heat break, nozzle, convection)
}

# hotend_stock: the default, a stock printer's hotend (a 40 W cartridge in an aluminium block with a
# brass nozzle). Marlin's MPC power, loss, fan and filament terms and sensor responsiveness (above),
# the block's capacity from its size, and the cartridge node every real hotend has between heater and
# block: the lag that sets the period and swing of M303's relay. Its conductance is chosen so that
# `M303 E0 S210 C8` on a fresh twin-serial gives Tu 19.0 s and a 6.1 C swing (tests/protocol/test_stock_autotune.py),
# within the hotend captures in hardware_logs (README section D: Tu 10.3..24 s, swings 4.7..9 C; the
# Artillery Genius Pro's stock hotend, Tu 18.2 s and 7-9 C, is the closest).
STOCK_BLOCK_HEAT_CAPACITY_J_K = 7.0  # V6-class block and nozzle: ~6.5 g aluminium x 0.9 + ~2.5 g brass x 0.38 J/(g K)
STOCK_CARTRIDGE_HEAT_CAPACITY_J_K = 1.0  # 6 x 20 mm cartridge: ~2 g of sheath, MgO and coil x 0.5 J/(g K)
STOCK_CARTRIDGE_XFER_W_K = 0.5  # chosen for the M303 period above

# bed: fitted to the chesleavens heat-up (README section A, session 0, 660 s from the heater's
# first line, the logged pwm replayed, ambient 25.2 C) by `python -m tools.validation.plant_check --fit`.
BED_POWER_W = 220.0  # assumed: a 24 V, 235 mm Ender-3-class bed (~2.6 ohm); the log fixes P/C and A/P
BED_HEAT_CAPACITY_J_K = 566.5  # fitted
BED_SENSOR_RESPONSIVENESS_PER_S = 0.2765  # fitted
BED_AMBIENT_XFER_W_K = 1.587  # fitted
BED_AREA_M2 = 2 * 0.235 * 0.235  # both faces, for the optional radiation

# bed_mk3: seed 004's MK3 aluminium bed, "a 90-watt heater", duty capped at 220/255 on 24 V,
# "about 10 minutes to reach 100 C". The loss is solved from that time (25 C ambient assumed) by
# `python -m tools.validation.plant_check --fit`; the sensor lag is the bed fit's.
MK3_POWER_W = 90.0
MK3_HEAT_CAPACITY_J_K = 333.0  # 214 x 214 x 3 mm aluminium: 371 g x 0.897 J/(g K)
MK3_AMBIENT_XFER_W_K = 0.7785  # solved
MK3_AREA_M2 = 2 * 0.214 * 0.214


class Conditions(NamedTuple):
    """The key a lumped plant's discretisation is cached under."""

    fan: float  # 0..1 in steps of 1/255
    flow_mm_s: float  # filament feed, >= 0
    ambient_c: float | None = None  # radiating plants only
    block_bin_c: float | None = None  # radiating plants only: the linearisation temperature


def _check(spec, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()) -> None:
    """Range checks of a spec's fields; ValueError names the parameter."""
    for name in positive + non_negative:
        value = getattr(spec, name)
        if not (value > 0 if name in positive else value >= 0):
            raise ValueError(f"plant parameter {name}={value!r}: must be {'> 0' if name in positive else '>= 0'}")


@dataclass(frozen=True)
class Lumped:
    """Block, sensor and optional cartridge nodes (Marlin's MPC model when there is no cartridge).

    C dTb/dt = P u - k (Tb - Ta),  k = A + fan (F - A) + H flow (+ radiation),  dTs/dt = R (Tb - Ts).
    With a cartridge the heat enters it instead: Cc dTc/dt = P u - G (Tc - Tb), and the block gains
    G (Tc - Tb). States [block, sensor, (cartridge)] in degC; disturbance d = [ambient_c].
    """

    power_w: float  # P, at u = 1
    block_heat_capacity_j_k: float  # C
    sensor_responsiveness_per_s: float  # R
    ambient_xfer_w_k: float  # A, part fan off
    fan_ambient_xfer_w_k: float  # F, part fan full
    filament_heat_capacity_j_k_mm: float = 0.0  # H, per mm/s of filament fed
    cartridge_heat_capacity_j_k: float = 0.0  # Cc; 0: no cartridge node
    cartridge_xfer_w_k: float = 0.0  # G, cartridge to block
    emissivity: float = 0.0  # 0: no radiation
    radiating_area_m2: float = 0.0

    delay_ticks: ClassVar[int] = 0
    delay_s: ClassVar[float] = 0.0
    world_inputs: ClassVar[bool] = True  # the part fan and the filament flow act on it

    def __post_init__(self):
        _check(self, positive=("block_heat_capacity_j_k", "sensor_responsiveness_per_s"),
               non_negative=("power_w", "ambient_xfer_w_k", "fan_ambient_xfer_w_k", "filament_heat_capacity_j_k_mm",
                             "cartridge_heat_capacity_j_k", "emissivity", "radiating_area_m2"))
        if self.cartridge_heat_capacity_j_k:
            _check(self, positive=("cartridge_xfer_w_k",))
        if self.emissivity > 1:
            raise ValueError(f"plant parameter emissivity={self.emissivity!r}: must be <= 1")

    @property
    def linear(self) -> bool:
        return not (self.emissivity and self.radiating_area_m2)

    @property
    def input_full_scale(self) -> float:
        """The heater input at duty 1: power_w, in W."""
        return self.power_w

    def rest_lti(self, ambient_c: float) -> Lti:
        """The model at rest: part fan off, no flow, linearised at ambient_c."""
        return self.lti(self.conditions(0.0, 0.0, ambient_c, ambient_c))

    def conditions(self, fan: float, flow_mm_s: float, ambient_c: float, block_c: float) -> Conditions:
        """The cache key: fan and flow rounded; ambient and the block's 0.5 C bin if radiating."""
        key = Conditions(round(fan * FAN_STEPS) / FAN_STEPS, round(max(0.0, flow_mm_s), FLOW_DIGITS))
        if self.linear:
            return key
        return key._replace(ambient_c=ambient_c, block_bin_c=round(block_c / RADIATION_BIN_C) * RADIATION_BIN_C)

    def radiation_w_k(self, block_c: float, ambient_c: float) -> float:
        """Secant conductance of sigma eps area (Tb^4 - Ta^4): exact loss h (Tb - Ta) at block_c."""
        tb, ta = block_c + KELVIN, ambient_c + KELVIN
        return STEFAN_BOLTZMANN_W_M2_K4 * self.emissivity * self.radiating_area_m2 * (tb * tb + ta * ta) * (tb + ta)

    def lti(self, key: Conditions) -> Lti:
        k_w_k = (self.ambient_xfer_w_k + key.fan * (self.fan_ambient_xfer_w_k - self.ambient_xfer_w_k)
                 + self.filament_heat_capacity_j_k_mm * key.flow_mm_s)
        if key.block_bin_c is not None and key.ambient_c is not None:  # both set for radiating plants
            k_w_k += self.radiation_w_k(key.block_bin_c, key.ambient_c)
        c_b, r = self.block_heat_capacity_j_k, self.sensor_responsiveness_per_s
        n = 3 if self.cartridge_heat_capacity_j_k else 2
        a, b, e = np.zeros((n, n)), np.zeros(n), np.zeros((n, 1))
        a[0, 0], e[0, 0] = -k_w_k / c_b, k_w_k / c_b
        a[1, 0], a[1, 1] = r, -r
        if n == 3:
            c_c, g = self.cartridge_heat_capacity_j_k, self.cartridge_xfer_w_k
            a[0, 0] -= g / c_b
            a[0, 2] = g / c_b
            a[2, 0], a[2, 2] = g / c_c, -g / c_c
            b[2] = self.power_w / c_c
        else:
            b[0] = self.power_w / c_b
        c = np.zeros((2, n))
        c[SENSOR, 1] = c[BLOCK, 0] = 1.0
        return Lti(a, b, e, c, np.zeros((2, 1)))

    def initial_state(self, ambient_c: float, start_c: float) -> np.ndarray:
        """Every node at start_c."""
        return np.full(3 if self.cartridge_heat_capacity_j_k else 2, float(start_c))


@dataclass(frozen=True)
class TransferFunction:
    """Temperature rise above ambient = G(s) applied to (u input_full_scale), in the paper's units:

    G(s) = gain (lead_s s + 1) e^(-delay_s s)
           / ((lag1_s s + 1)(lag2_s s + 1)(lag3_s s + 1)(tau^2 s^2 + 2 damping tau s + 1))

    with tau = time_constant_s; a zero lead, lag or tau drops its factor. One output: the sensor and
    block rows are both the temperature. Fan and flow do not act on these models.
    """

    gain: float  # degC per unit of the paper's input
    input_full_scale: float  # the paper's input at u = 1
    lag1_s: float = 0.0
    lag2_s: float = 0.0
    lag3_s: float = 0.0
    lead_s: float = 0.0
    time_constant_s: float = 0.0
    damping: float = 1.0
    delay_s: float = 0.0

    linear: ClassVar[bool] = True
    world_inputs: ClassVar[bool] = False  # no fan or flow terms: a disturbance is a load at the input

    def __post_init__(self):
        _check(self, positive=("input_full_scale", "damping"),
               non_negative=("lag1_s", "lag2_s", "lag3_s", "time_constant_s", "delay_s"))
        if not self.gain:
            raise ValueError(f"plant parameter gain={self.gain!r}: must be non-zero")
        num, den = self.polynomials()
        if len(den) <= len(num):
            raise ValueError("plant parameters: a transfer function needs more poles than zeros "
                             "(set a lag or time_constant_s)")

    @property
    def delay_ticks(self) -> int:
        return round(self.delay_s / TICK_S)

    def polynomials(self) -> tuple[np.ndarray, np.ndarray]:
        """G(s) without the dead time: numerator and denominator, highest power first."""
        num = np.array([self.gain * self.lead_s, self.gain] if self.lead_s else [self.gain])
        den = np.array([1.0])
        for lag_s in (self.lag1_s, self.lag2_s, self.lag3_s):
            if lag_s:
                den = np.polymul(den, [lag_s, 1.0])
        if self.time_constant_s:
            tau = self.time_constant_s
            den = np.polymul(den, [tau * tau, 2 * self.damping * tau, 1.0])
        return num, den

    def conditions(self, fan: float, flow_mm_s: float, ambient_c: float, block_c: float) -> None:
        return None

    def lti(self, key: None = None) -> Lti:
        import scipy.signal  # here, not at start-up: only a transfer-function plant needs it

        a, b, c, _ = scipy.signal.tf2ss(*self.polynomials())
        n = a.shape[0]
        return Lti(a, b[:, 0] * self.input_full_scale, np.zeros((n, 1)), np.vstack((c, c)), np.ones((2, 1)))

    def rest_lti(self, ambient_c: float) -> Lti:
        """The model (it has no operating point)."""
        return self.lti()

    def initial_state(self, ambient_c: float, start_c: float) -> np.ndarray:
        """The equilibrium that holds start_c (the steady state under the input that would keep it there)."""
        lti = self.lti()
        x_full = -np.linalg.solve(lti.a, lti.b)  # steady state at u = 1
        return x_full * (start_c - ambient_c) / (lti.c[SENSOR] @ x_full)


Spec = Lumped | TransferFunction


def respec(spec: Spec, changes: Mapping[str, float]) -> Spec:
    """``spec`` with the named fields set to new values (TypeError on a name the spec lacks)."""
    if isinstance(spec, Lumped):
        return dataclasses.replace(spec, **changes)
    return dataclasses.replace(spec, **changes)


class Plant(LinearPlant):
    """A preset's model stepped on the tick, with the world's inputs: part fan, filament flow, ambient."""

    def __init__(self, preset: str, spec: Spec, ambient_c: float = 25.0, initial_c: float | None = None):
        start_c = ambient_c if initial_c is None else initial_c
        self.preset = preset
        self.spec = spec
        self.linear = spec.linear
        self.fan = 0.0
        self.flow_mm_s = 0.0
        model_for: Callable = spec.lti  # each spec's lti takes its own conditions key
        super().__init__(model_for, spec.conditions(0.0, 0.0, ambient_c, start_c),
                         spec.initial_state(ambient_c, start_c), [ambient_c], spec.delay_ticks)

    @property
    def ambient_c(self) -> float:
        return float(self.d[0])

    def __repr__(self) -> str:
        temps = self.temps_c()
        return f"Plant({self.preset!r}, {type(self.spec).__name__}, sensor {temps[SENSOR]:.2f} C, block " \
               f"{temps[BLOCK]:.2f} C, fan {self.fan:g}, flow {self.flow_mm_s:g} mm/s, ambient {self.ambient_c:g} C)"

    def set_inputs(self, fan: float, flow_mm_s: float, ambient_c: float) -> None:
        """New part-fan speed (0..1), filament feed (mm/s) and ambient (degC): a scenario event."""
        if not 0.0 <= fan <= 1.0:
            raise ValueError(f"fan={fan!r}: must be within 0..1")
        self.fan, self.flow_mm_s = float(fan), float(flow_mm_s)
        self.d = np.array([ambient_c], dtype=float)
        self._update_conditions()

    def relinearise(self) -> None:
        """Between runs: a radiating plant moves its linearisation to the block's current bin."""
        if not self.linear:
            self._update_conditions()

    def _update_conditions(self) -> None:
        key = self.spec.conditions(self.fan, self.flow_mm_s, self.ambient_c, float(self.temps_c()[BLOCK]))
        if key != self.conditions:
            self.set_conditions(key)


class PresetInfo(NamedTuple):
    description: str
    units: str
    source: str


_LUMPED_UNITS = ("u: 0..1 of power_w; temperatures degC; power_w W, heat capacities J/K, "
                 "sensor_responsiveness_per_s 1/s, xfer W/K, filament J/K per mm/s, area m^2")

SPECS: dict[str, Spec] = {
    "hotend": Lumped(MPC_HEATER_POWER_W, MPC_BLOCK_HEAT_CAPACITY_J_K, MPC_SENSOR_RESPONSIVENESS_PER_S,
                     MPC_AMBIENT_XFER_W_K, MPC_AMBIENT_XFER_FAN255_W_K, MPC_FILAMENT_HEAT_CAPACITY_J_K_MM,
                     radiating_area_m2=V6_BLOCK_AREA_M2),
    "hotend_stock": Lumped(MPC_HEATER_POWER_W, STOCK_BLOCK_HEAT_CAPACITY_J_K, MPC_SENSOR_RESPONSIVENESS_PER_S,
                           MPC_AMBIENT_XFER_W_K, MPC_AMBIENT_XFER_FAN255_W_K, MPC_FILAMENT_HEAT_CAPACITY_J_K_MM,
                           STOCK_CARTRIDGE_HEAT_CAPACITY_J_K, STOCK_CARTRIDGE_XFER_W_K,
                           radiating_area_m2=V6_BLOCK_AREA_M2),
    "hotend_cartridge": Lumped(ONION_POWER_W, ONION_BLOCK_HEAT_CAPACITY_J_K, ONION_SENSOR_RESPONSIVENESS_PER_S,
                               ONION_AMBIENT_XFER_W_K, ONION_FAN_XFER_W_K, MPC_FILAMENT_HEAT_CAPACITY_J_K_MM,
                               ONION_CARTRIDGE_HEAT_CAPACITY_J_K, ONION_CARTRIDGE_XFER_W_K,
                               radiating_area_m2=V6_BLOCK_AREA_M2),
    "bed": Lumped(BED_POWER_W, BED_HEAT_CAPACITY_J_K, BED_SENSOR_RESPONSIVENESS_PER_S, BED_AMBIENT_XFER_W_K,
                  BED_AMBIENT_XFER_W_K, radiating_area_m2=BED_AREA_M2),
    "bed_mk3": Lumped(MK3_POWER_W, MK3_HEAT_CAPACITY_J_K, BED_SENSOR_RESPONSIVENESS_PER_S, MK3_AMBIENT_XFER_W_K,
                      MK3_AMBIENT_XFER_W_K, radiating_area_m2=MK3_AREA_M2),
    "seed000_first": TransferFunction(gain=5.0, input_full_scale=40.0, lag1_s=10.0),
    "seed000_second": TransferFunction(gain=5.0, input_full_scale=40.0, time_constant_s=10.0, damping=0.7),
    "seed001_fopdt": TransferFunction(gain=0.196, input_full_scale=2000.0, lag1_s=24.0, delay_s=20.7),
    # 1.014 / (s^2 + 0.05 s + 0.001) = 1014 / (tau^2 s^2 + 2 zeta tau s + 1), tau = 1/sqrt(0.001)
    "seed002_sopdt": TransferFunction(gain=1.014 / 0.001, input_full_scale=1.0, time_constant_s=1 / math.sqrt(0.001),
                                      damping=0.05 / (2 * math.sqrt(0.001)), delay_s=20.0),
    "seed003_third": TransferFunction(gain=0.72653, input_full_scale=550.0, lead_s=163.4092, lag1_s=634.1044,
                                      lag2_s=61.5524, lag3_s=0.50895, delay_s=5.0),
}

DEFAULT_HOTEND = "hotend_stock"  # the plants a twin gets when none is named
DEFAULT_BED = "bed"

PRESETS: dict[str, PresetInfo] = {
    "hotend": PresetInfo(
        "hotend, two nodes (block, sensor): Marlin's MPC model with its defaults",
        _LUMPED_UNITS,
        "Marlin 2.1 MPC defaults (Configuration.h; reference/marlin_heater.md section 8)"),
    "hotend_stock": PresetInfo(
        "the default: a stock printer's 40 W hotend, three nodes (cartridge, block, sensor) whose M303 period "
        "and swing fall among real hotends'",
        _LUMPED_UNITS,
        "Marlin 2.1 MPC loss and sensor terms; block from its size; cartridge lag chosen so that M303 E0 S210 C8 "
        "gives Tu 19.0 s (hardware_logs README D: Tu 10-24 s)"),
    "hotend_cartridge": PresetInfo(
        "hotend, three nodes (cartridge, block, sensor) fitted to a real pulse test and its overshoot after cut-off",
        _LUMPED_UNITS,
        "onionheater heattest_200 no-fan pulse (hardware_logs README B), python -m tools.validation.plant_check --fit"),
    "bed": PresetInfo(
        "24 V 235 mm bed, 220 W assumed: 26 -> 65 C in about 2 min, 25 % duty at 60 C",
        _LUMPED_UNITS,
        "chesleavens klippy Stats heat-up (hardware_logs README A), python -m tools.validation.plant_check --fit"),
    "bed_mk3": PresetInfo(
        "MK3 aluminium bed, 90 W: about 10 min to 100 C at duty 220/255",
        _LUMPED_UNITS,
        "seed 004 (El-Fakharany et al. 2018) sections 1, 3, 4.1; capacity from the plate's size"),
    "seed000_first": PresetInfo(
        "first-order hotend 5/(10 s + 1) C/W",
        "u: 0..1 of input_full_scale W (paper's input: heater power); gain C/W; output ambient + rise",
        "seed 000 (Lab Units 13 & 14), section 2 example extruder"),
    "seed000_second": PresetInfo(
        "second-order hotend 5/(100 s^2 + 14 s + 1) C/W",
        "u: 0..1 of input_full_scale W (paper's input: heater power); gain C/W; output ambient + rise",
        "seed 000, section 2 second-order form with the section 4 simulation's zeta = 0.7"),
    "seed001_fopdt": PresetInfo(
        "FOPDT nozzle 0.196 e^-20.7s / (24 s + 1)",
        "u: 0..1 of input_full_scale degC of the paper's temperature command; gain C/C; output ambient + rise",
        "seed 001 (Fuzzy-PID nozzle control), equation (9)"),
    "seed002_sopdt": PresetInfo(
        "SOPDT nozzle 1.014 e^-20s / (s^2 + 0.05 s + 0.001)",
        "u: 0..1 of input_full_scale = 1, the heater duty (Klipper's 0..1, inferred); gain C per unit duty; "
        "output ambient + rise",
        "seed 002 (OCALO-PID, Zhou et al. 2024), equation (15)"),
    "seed003_third": PresetInfo(
        "third order with a zero: 0.7265 (163.4 s + 1) e^-5s / ((634.1 s + 1)(61.55 s + 1)(0.509 s + 1))",
        "u: 0..1 of input_full_scale units of the paper's input (not stated in the paper); gain C per unit; "
        "output ambient + rise",
        "seed 003 (MSDI PID tuning), identified model of the extruder"),
}


def make_plant(preset: str = DEFAULT_HOTEND, *, ambient_c: float = 25.0, initial_c: float | None = None, **params) -> Plant:
    """A preset's plant at ambient_c, every node at initial_c (default: ambient); params override the preset's.

    ValueError names an unknown preset or parameter (listing the valid ones) or a value out of range.
    """
    if preset not in SPECS:
        raise ValueError(f"unknown plant preset {preset!r}; valid: {', '.join(SPECS)}")
    checked("ambient_c", ambient_c, *PHYSICAL_RANGE_C, "C", above=True)
    if initial_c is not None:
        checked("initial_c", initial_c, *PHYSICAL_RANGE_C, "C", above=True)
    spec = SPECS[preset]
    names = [field.name for field in dataclasses.fields(spec)]
    for name, value in params.items():
        if name not in names:
            raise UserError(f"unknown parameter {name!r} for plant preset {preset!r}; valid: {', '.join(names)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise UserError(f"plant parameter {name}={value!r}: must be a finite number")
        if abs(value) > PARAMETER_MAX:
            raise UserError(f"plant parameter {name}={value!r}: beyond {PARAMETER_MAX:g}, no heater's (the model "
                             "would overflow)")
    return Plant(preset, respec(spec, {name: float(value) for name, value in params.items()}),
                 ambient_c, initial_c)
