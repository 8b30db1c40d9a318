/* The pneumatic muscle as a MuJoCo actuator plugin: "wpam_mj.muscle".

   The compiled form of the Python engine (wpam_mj/simulation/engine.py), which is the readable
   definition: each function below carries the name of the Python function it mirrors and
   evaluates every expression in the Python order, so the two are bit-identical
   (tests/test_plugin.py). The physics and its sources are in the Python modules:
   BraidGeometry (wpam_mj/physics/geometry.py; Chou & Hannaford 1996), MuscleModel
   (wpam_mj/physics/muscle.py; paper eqs. 1-7), Regulator, Chamber, mass_flow (wpam_mj/physics/pneumatics.py;
   ISO 6358), PoFeedback and the Pi feedforward (wpam_mj/control/controllers.py; paper §4).

   Built with -ffp-contract=off and without -ffast-math (no fused multiply-adds, no
   reassociation); libm's sqrt, pow, sin, cos, expm1 are the functions Python's floats call.
   min/max follow Python's builtins (first argument wins ties).

   One plugin instance is one muscle. The actuators that name the instance are its input
   channels in model order (WPAM_CHANNELS of the generated header; docs/plugin.md): the
   first must act on the muscle's tendon and carries the force, the others carry none.
   Per step:
     compute (mj_fwdActuation, after the constraint rows are made, before the solve):
       contraction x = tendon_length0 - ten_length, v = -ten_velocity; the Po controller's
       output from its committed state (nothing committed: compute may run more than once
       per step); the tension from the chamber pressures -> actuator_force = -tension
       (along the tendon's length); the friction level -> this simulation's friction row
       of the tendon (efc_frictionloss: stiction per simulation through the constraint
       solver, the model's tendon_frictionloss untouched).
     advance (after integration, once per step): the controller's state committed, the
       regulators and chambers advanced from the values compute used.
   Everything that changes lives in plugin_state (layout WPAM_STATE); constants derived
   from the configuration are cached per mjData and re-derived whenever the model or its
   configuration differs from the cached one (a batch may run many models on one mjData).

   Units: SI throughout (m, m/s, Pa gauge unless named absolute, N, kg/s, s). */

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>
#include <mujoco/mjplugin.h>

#include "wpam_plugin_tables.h" /* generated from wpam_mj/physics/params.py by wpam_mj/simulation/plugin.py */

#define PI 3.14159265358979323846 /* rounds to math.pi */

/* columns of WPAM_PARAMS(F): F(NAME, key, unit, lo, hi, lo_open) */
#define WPAM_LO(NAME, key, unit, lo, hi, lo_open) lo,
#define WPAM_HI(NAME, key, unit, lo, hi, lo_open) hi,
#define WPAM_LO_OPEN(NAME, key, unit, lo, hi, lo_open) lo_open,
#define WPAM_UNIT(NAME, key, unit, lo, hi, lo_open) unit,

static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* ---- enums from the generated tables ---- */
#define AS_PARAM_ENUM(NAME, key, unit, lo, hi, lo_open, ...) P_##NAME,
#define AS_STATE_ENUM(NAME, name) S_##NAME,
#define AS_CONTROL_ENUM(NAME, name, nmin, nmax, feedback) C_##NAME,
enum { WPAM_PARAMS(AS_PARAM_ENUM) P_COUNT };
enum { WPAM_STATE(AS_STATE_ENUM) S_COUNT };
enum { WPAM_CONTROLS(AS_CONTROL_ENUM) C_COUNT };

#define AS_KEY(NAME, key, ...) key,
#define AS_CONTROL_NAME(NAME, name, ...) #name,
static const char* const PARAM_KEYS[] = {WPAM_PARAMS(AS_KEY)};
static const char* const CONTROL_NAMES[] = {WPAM_CONTROLS(AS_CONTROL_NAME)};
#define AS_NMIN(NAME, name, nmin, nmax, feedback) nmin,
#define AS_NMAX(NAME, name, nmin, nmax, feedback) nmax,
#define AS_FEEDBACK(NAME, name, nmin, nmax, feedback) feedback,
static const int CONTROL_NMIN[] = {WPAM_CONTROLS(AS_NMIN)};
static const int CONTROL_NMAX[] = {WPAM_CONTROLS(AS_NMAX)};
static const int CONTROL_FEEDBACK[] = {WPAM_CONTROLS(AS_FEEDBACK)};

/* Every configuration attribute: the instance keys, then every parameter by name. */
#define AS_ATTRIBUTE(NAME, key, ...) key,
static const char* const ATTRIBUTES[] = {WPAM_INSTANCE_KEYS WPAM_PARAMS(AS_ATTRIBUTE)};
#define NATTRIBUTE ((int)(sizeof(ATTRIBUTES) / sizeof(ATTRIBUTES[0])))

/* ---- the constants of one instance: parameters and what is derived from them ---- */

typedef struct {
  double p[P_COUNT];          /* parameters by WPAM_PARAMS, SI */
  int control;                /* C_* */
  int start_at_rest;          /* 1: the first step's commands were held before the run */
  double feedforward_load;    /* load the Pi feedforward holds [N] */
  double length0;             /* tendon length at which x = contraction0 [m] */
  double contraction0;        /* contraction in the model's reference pose [m] */
  int tendon;                 /* the muscle's tendon id */
  int channel[WPAM_MAX_CHANNELS]; /* actuator ids of the input channels */
  int nchannel;
  /* derived, each with the expression of the Python code it stands for */
  double thread_length, turns, max_contraction;    /* BraidGeometry.from_params */
  double thread_sq, volume_denom, diameter_denom;  /* b ** 2, 4 pi n ** 2, n pi */
  double lag_alpha;           /* RunConstants.lag_alpha */
  int delay_steps;            /* RunConstants.delay_steps */
  double bag_volume;          /* pneumatics.outer_bag_volume */
  double pa_per_unit, integral0, kd;  /* PoFeedback */
  double dt;
} Constants;

/* Cache of one mjData: the constants of every instance, valid for one model and one
   configuration (compared whole on every call: cheap against a physics step). */
typedef struct {
  const mjModel* model;
  double timestep;
  char* attr;      /* copy of m->plugin_attr */
  int nattr;
  Constants* k;    /* by instance id */
  int nplugin;
} Cache;

/* Parse one instance's configuration into k; on error write a one-line message. */
static int parse_config(const mjModel* m, int instance, Constants* k, int channels, char* err,
                        int nerr);

/* ---- BraidGeometry (wpam_mj/physics/geometry.py) ---- */

static double geom_diameter(const Constants* k, double x) {
  double L = k->p[P_BRAID_NATURAL_LENGTH] - x;
  return sqrt(k->thread_sq - L * L) / k->diameter_denom;
}

static double geom_volume(const Constants* k, double x) {
  double L = k->p[P_BRAID_NATURAL_LENGTH] - x;
  return L * (k->thread_sq - L * L) / k->volume_denom;
}

static double geom_area(const Constants* k, double x) {
  double L = k->p[P_BRAID_NATURAL_LENGTH] - x;
  return (3.0 * L * L - k->thread_sq) / k->volume_denom;
}

/* ---- MuscleModel (wpam_mj/physics/muscle.py); gauge pressures ---- */

static double muscle_rubber_force(const Constants* k, double x) {
  return PI * k->p[P_MUSCLE_RUBBER_STIFFNESS]
         * (geom_diameter(k, x) - k->p[P_BRAID_NATURAL_DIAMETER]);
}

static double muscle_tension(const Constants* k, double x, double pi, double po) {
  double dp = pi > po ? pi - po : 0.0;
  return (k->p[P_MUSCLE_OUTPUT_COEFF] * (dp * geom_area(k, x) - muscle_rubber_force(k, x))
          - k->p[P_MUSCLE_AXIAL_AREA] * po);
}

static double muscle_friction(const Constants* k, double x, double pi, double po) {
  double dp = pi > po ? pi - po : 0.0;
  return k->p[P_MUSCLE_FRICTION_COEFF] * dp * geom_area(k, x) + k->p[P_MUSCLE_FRICTION_CONST];
}

/* MuscleModel.equilibrium_pressure then control.pi_feedforward's clip: the Pi [Pa] that
   holds x_ref under the feedforward load at Po = po_feedforward, on the branch
   feedforward_friction; p_max where the braid cannot hold it (inf, clipped). */
static double pi_feedforward(const Constants* k, double x_ref) {
  double s = k->p[P_CONTROLLER_FEEDFORWARD_FRICTION];
  double po = k->p[P_CONTROLLER_PO_FEEDFORWARD];
  double gain = (k->p[P_MUSCLE_OUTPUT_COEFF] - s * k->p[P_MUSCLE_FRICTION_COEFF])
                * geom_area(k, x_ref);
  double rhs = py_max(k->feedforward_load + k->p[P_MUSCLE_AXIAL_AREA] * po
                      + k->p[P_MUSCLE_OUTPUT_COEFF] * muscle_rubber_force(k, x_ref)
                      + s * k->p[P_MUSCLE_FRICTION_CONST], 0.0);
  double pi = gain > 0.0 ? po + rhs / gain : INFINITY;
  /* np.clip(pi, lo, hi) = min(max(pi, lo), hi) */
  return py_min(py_max(pi, k->p[P_PNEUMATICS_P_MIN]), k->p[P_PNEUMATICS_P_MAX]);
}

/* ---- pneumatics (wpam_mj/physics/pneumatics.py); absolute pressures ---- */

static double iso6358_psi(double r, double b) {
  double q;
  if (r <= b) return 1.0;
  if (r <= WPAM_R_LAMINAR) {
    q = (r - b) / (1.0 - b);
    return sqrt(1.0 - q * q);
  }
  q = (WPAM_R_LAMINAR - b) / (1.0 - b);
  return sqrt(1.0 - q * q) * (1.0 - r) / (1.0 - WPAM_R_LAMINAR);
}

static double mass_flow(double p_source, double p_chamber, double c, double b) {
  if (p_source >= p_chamber)
    return c * WPAM_RHO_0 * p_source * iso6358_psi(p_chamber / p_source, b);
  return -c * WPAM_RHO_0 * p_chamber * iso6358_psi(p_source / p_chamber, b);
}

/* Chamber.step: one explicit Euler step of dp/dt = (R T0 m_dot - p dV/dt) / V. */
static double chamber_step(const Constants* k, double p, double conductance, double p_source,
                           double volume, double dvdx, double v) {
  double m = mass_flow(p_source, p, conductance, k->p[P_PNEUMATICS_CRITICAL_RATIO]);
  return p + k->dt * (WPAM_RT0 * m - p * dvdx * v) / volume;
}

/* Regulator.update: the command through the dead time (ring buffer `queue`, shared head),
   clamped, then the first-order lag. Returns the new set point. */
static double regulator_update(const Constants* k, double* set_point, double* queue,
                               int head, double command) {
  double clamped;
  if (k->delay_steps) {
    double held = queue[head];
    queue[head] = command;
    command = held;
  }
  clamped = py_min(py_max(command, 0.0), k->p[P_PNEUMATICS_P_MAX]);
  *set_point += k->lag_alpha * (clamped - *set_point);
  return *set_point;
}

/* Regulator.rest */
static void regulator_rest(const Constants* k, double* set_point, double* queue,
                           double command) {
  int i;
  for (i = 0; i < k->delay_steps; i++) queue[i] = command;
  *set_point = py_min(py_max(command, 0.0), k->p[P_PNEUMATICS_P_MAX]);
}

/* ---- PoFeedback.update (wpam_mj/control/controllers.py), split: evaluate, then commit ---- */

static double feedback_output(const Constants* k, const double* s, double x, double x_ref,
                              double po_ff, double* integral_next, double* derivative,
                              double* e_out) {
  const double* p = k->p;
  double e = (x - x_ref) / WPAM_MM;
  double e_prev = s[S_HAS_PREV] != 0.0 ? s[S_E_PREV] : e;
  double integral = s[S_INTEGRAL] + e * k->dt;
  double u;
  *derivative = (p[P_CONTROLLER_DERIVATIVE_FILTER] * s[S_DERIVATIVE] + (e - e_prev))
                / (p[P_CONTROLLER_DERIVATIVE_FILTER] + k->dt);
  u = (p[P_CONTROLLER_KP] * e + p[P_CONTROLLER_KI] * integral + k->kd * *derivative)
      * k->pa_per_unit + po_ff;
  *integral_next = s[S_INTEGRAL];
  if (u > p[P_CONTROLLER_PO_CAP]) {
    u = p[P_CONTROLLER_PO_CAP];
    if (e < 0.0) *integral_next = integral;
  } else if (u < p[P_PNEUMATICS_P_MIN]) {
    u = p[P_PNEUMATICS_P_MIN];
    if (e > 0.0) *integral_next = integral;
  } else {
    *integral_next = integral;
  }
  *e_out = e;
  return u;
}

/* ---- the state of one instance ---- */

static double* queue_i(double* s) { return s + S_COUNT; }
static double* queue_o(const Constants* k, double* s) { return s + S_COUNT + k->delay_steps; }

/* Initial state: vented chambers, empty regulators, controller at its bumpless start. */
static void state_reset(const Constants* k, double* s) {
  int i, n = S_COUNT + 2 * k->delay_steps;
  for (i = 0; i < n; i++) s[i] = 0.0;
  s[S_X_REF] = NAN;
  s[S_P_I] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_P_O] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_INTEGRAL] = k->integral0;
  s[S_REST_PENDING] = k->start_at_rest;
}

/* Plant.rest: regulators settled on the commands, chambers at their set points. */
static void plant_rest(const Constants* k, double* s, double pi_cmd, double po_cmd) {
  double pa = k->p[P_PNEUMATICS_ATMOSPHERE];
  regulator_rest(k, &s[S_PI_REG], queue_i(s), pi_cmd);
  regulator_rest(k, &s[S_PO_REG], queue_o(k, s), po_cmd);
  s[S_P_I] = s[S_PI_REG] + pa;
  s[S_P_O] = s[S_PO_REG] + pa;
}

/* ---- configuration ---- */

static int find_key(const char* key, const char* const* list, int n) {
  int i;
  for (i = 0; i < n; i++)
    if (!strcmp(key, list[i])) return i;
  return -1;
}

/* A number from the configuration: strtod must consume the whole value. */
static int parse_number(const char* text, double* out) {
  char* end;
  if (!text || !text[0]) return 0;
  *out = strtod(text, &end);
  while (*end == ' ') end++;
  return *end == '\0' && isfinite(*out);
}

static int fail(char* err, int nerr, const char* message) {
  snprintf(err, nerr, "%s", message);
  return -1;
}

/* channels = 0: the parameters only (at compile time, before the actuators exist). */
static int parse_config(const mjModel* m, int instance, Constants* k, int channels, char* err,
                        int nerr) {
  static const double PRESET_DEFAULTS[WPAM_NPRESET][P_COUNT] = WPAM_PRESET_DEFAULTS;
  static const double LO[] = {WPAM_PARAMS(WPAM_LO)};
  static const double HI[] = {WPAM_PARAMS(WPAM_HI)};
  static const int LO_OPEN[] = {WPAM_PARAMS(WPAM_LO_OPEN)};
  static const char* const UNITS[] = {WPAM_PARAMS(WPAM_UNIT)};
  static const char* const PRESETS[] = {WPAM_PRESETS};
  static const int PRESET_OUTER[] = {WPAM_PRESET_OUTER};  /* MuscleType.outer_chamber */
  const char* name = mj_id2name(m, mjOBJ_PLUGIN, instance);
  const char* text;
  char msg[400];
  int i, preset = 0;
  double value;
  memset(k, 0, sizeof(*k));
  name = name ? name : "(unnamed)";

  text = mj_getPluginConfig(m, instance, "preset");
  if (text && text[0]) {
    preset = find_key(text, PRESETS, WPAM_NPRESET);
    if (preset < 0) {
      snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': preset = '%s' is not one "
               "of: %s", name, text, WPAM_PRESET_LIST);
      return fail(err, nerr, msg);
    }
  }
  for (i = 0; i < P_COUNT; i++) {
    k->p[i] = PRESET_DEFAULTS[preset][i];
    text = mj_getPluginConfig(m, instance, PARAM_KEYS[i]);
    if (!text || !text[0]) continue;
    if (!parse_number(text, &value) || (LO_OPEN[i] ? value <= LO[i] : value < LO[i])
        || value > HI[i]) {
      snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': %s = '%s' %s is outside "
               "the allowed range %s%.6g, %.6g] %s", name, PARAM_KEYS[i], text, UNITS[i],
               LO_OPEN[i] ? "(" : "[", LO[i], HI[i], UNITS[i]);
      return fail(err, nerr, msg);
    }
    k->p[i] = value;
  }

  text = mj_getPluginConfig(m, instance, "control");
  k->control = text && text[0] ? find_key(text, CONTROL_NAMES, C_COUNT) : 0;
  if (k->control < 0) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': control = '%s' is not one of: "
             "%s", name, text, WPAM_CONTROL_LIST);
    return fail(err, nerr, msg);
  }
  if (CONTROL_FEEDBACK[k->control] && !PRESET_OUTER[preset]) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': preset '%s' has no outer "
             "chamber for Po feedback (control = '%s'); use control = 'open'", name,
             PRESETS[preset], CONTROL_NAMES[k->control]);
    return fail(err, nerr, msg);
  }
  text = mj_getPluginConfig(m, instance, "start");
  if (text && text[0] && strcmp(text, "vented") && strcmp(text, "rest")) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': start = '%s' is not one of: "
             "vented, rest", name, text);
    return fail(err, nerr, msg);
  }
  k->start_at_rest = text && !strcmp(text, "rest");
  text = mj_getPluginConfig(m, instance, "feedforward_load");
  k->feedforward_load = 0.0;
  if (text && text[0] && (!parse_number(text, &k->feedforward_load)
                          || k->feedforward_load < 0.0 || k->feedforward_load > 1e5)) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': feedforward_load = '%s' N is "
             "outside the allowed range [0, 100000] N", name, text);
    return fail(err, nerr, msg);
  }

  text = mj_getPluginConfig(m, instance, "contraction0");
  k->contraction0 = 0.0;
  if (text && text[0] && (!parse_number(text, &k->contraction0) || k->contraction0 < -1.0
                          || k->contraction0 > 1.0)) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': contraction0 = '%s' m is "
             "outside the allowed range [-1, 1] m", name, text);
    return fail(err, nerr, msg);
  }

  /* the cross-field checks of wpam_mj.physics.params */
  if (k->p[P_BRAID_MAX_DIAMETER] <= k->p[P_BRAID_NATURAL_DIAMETER])
    return fail(err, nerr, "wpam_mj.muscle: braid.max_diameter must exceed "
                "braid.natural_diameter");
  if (k->p[P_PNEUMATICS_P_MIN] >= k->p[P_PNEUMATICS_P_MAX])
    return fail(err, nerr, "wpam_mj.muscle: pneumatics.p_min must be below pneumatics.p_max");
  if (asin(py_min(1.0, sqrt(2.0 / 3.0) * k->p[P_BRAID_NATURAL_DIAMETER]
                          / k->p[P_BRAID_MAX_DIAMETER])) <= k->p[P_BRAID_BRAID_ANGLE])
    return fail(err, nerr, "wpam_mj.muscle: braid.braid_angle reaches the 54.7 deg locking "
                "angle before the bag fills to braid.max_diameter");

  /* derived constants, each as its Python original computes it */
  k->dt = m->opt.timestep;
  if (m->opt.integrator == mjINT_RK4)
    return fail(err, nerr, "wpam_mj.muscle: the RK4 integrator evaluates each step four "
                "times; use Euler, implicit or implicitfast (the pneumatics advance once per "
                "step)");
  if (!(k->dt > 0.0) || k->p[P_PNEUMATICS_DEAD_TIME] / k->dt > 1e6)
    return fail(err, nerr, "wpam_mj.muscle: the timestep must be positive and at least "
                "1e-6 of pneumatics.dead_time");
  k->delay_steps = (int)nearbyint(k->p[P_PNEUMATICS_DEAD_TIME] / k->dt); /* half-even */
  {
    double angle = k->p[P_BRAID_BRAID_ANGLE], L0 = k->p[P_BRAID_NATURAL_LENGTH];
    double b = L0 / cos(angle);
    double n = b * sin(angle) / (PI * k->p[P_BRAID_NATURAL_DIAMETER]);
    double radial = n * PI * k->p[P_BRAID_MAX_DIAMETER];
    k->thread_length = b;
    k->turns = n;
    k->max_contraction = L0 - sqrt(b * b - radial * radial);
    k->thread_sq = pow(b, 2.0);
    k->volume_denom = 4.0 * PI * pow(n, 2.0);
    k->diameter_denom = n * PI;
  }
  {
    double tau = k->p[P_PNEUMATICS_TIME_CONSTANT];
    k->lag_alpha = tau == 0.0 ? 1.0 : -expm1(-k->dt / tau);
  }
  k->bag_volume = PI * k->p[P_BRAID_OUTER_BAG_DIAMETER] * k->p[P_BRAID_OUTER_BAG_DIAMETER]
                  * k->p[P_BRAID_OUTER_BAG_LENGTH] / 4.0;
  k->pa_per_unit = k->p[P_CONTROLLER_COMMAND_SCALE] * WPAM_MPA;
  k->kd = k->control == C_PID ? k->p[P_CONTROLLER_KD] : 0.0;
  k->integral0 = !CONTROL_FEEDBACK[k->control] ? 0.0
                 : k->p[P_CONTROLLER_KI] > 0.0
                     ? k->p[P_CONTROLLER_PO_FEEDFORWARD] / k->pa_per_unit
                           / k->p[P_CONTROLLER_KI]
                     : 0.0;

  { /* pneumatics.stable_dt: the explicit chamber update is monotone for dt lambda <= 1 */
    double b = k->p[P_PNEUMATICS_CRITICAL_RATIO], tube = k->p[P_PNEUMATICS_TUBE_VOLUME];
    double v_i = geom_volume(k, 0.0) + tube;
    double v_o = k->bag_volume + tube - geom_volume(k, k->max_contraction)
                 - k->p[P_MUSCLE_AXIAL_AREA] * k->max_contraction;
    double slope = WPAM_RHO_0 * iso6358_psi(WPAM_R_LAMINAR, b) / (1.0 - WPAM_R_LAMINAR);
    double dt_i = v_i / (WPAM_RT0 * k->p[P_PNEUMATICS_INNER_CONDUCTANCE] * slope);
    double dt_o = v_o / (WPAM_RT0 * k->p[P_PNEUMATICS_OUTER_CONDUCTANCE] * slope);
    int inner = dt_i <= dt_o;
    if (k->dt > (inner ? dt_i : dt_o)) {
      snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': pneumatics.%s_conductance = "
               "%g m^3/(s Pa) fills its chamber too fast for the timestep %g s (the explicit "
               "chamber update would oscillate or diverge); use a timestep <= %.3g s", name,
               inner ? "inner" : "outer",
               k->p[inner ? P_PNEUMATICS_INNER_CONDUCTANCE : P_PNEUMATICS_OUTER_CONDUCTANCE],
               k->dt, inner ? dt_i : dt_o);
      return fail(err, nerr, msg);
    }
  }

  /* the channels: every actuator naming this instance, in model order */
  if (!channels) return 0;
  k->nchannel = 0;
  for (i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    if (k->nchannel == WPAM_MAX_CHANNELS) {
      k->nchannel++;
      break;
    }
    k->channel[k->nchannel++] = i;
  }
  if (k->nchannel < CONTROL_NMIN[k->control] || k->nchannel > CONTROL_NMAX[k->control]) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': control = '%s' takes %d to %d "
             "actuators (input channels), %d name the instance", name,
             CONTROL_NAMES[k->control], CONTROL_NMIN[k->control], CONTROL_NMAX[k->control],
             k->nchannel);
    return fail(err, nerr, msg);
  }
  if (m->actuator_trntype[k->channel[0]] != mjTRN_TENDON) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': its first actuator must act on "
             "a tendon (the muscle)", name);
    return fail(err, nerr, msg);
  }
  k->tendon = m->actuator_trnid[2 * k->channel[0]];
  if (m->tendon_frictionloss[k->tendon] <= 0.0) {
    snprintf(msg, sizeof(msg), "wpam_mj.muscle instance '%s': tendon '%s' needs a positive "
             "frictionloss (any value; the plugin sets the level every step)", name,
             mj_id2name(m, mjOBJ_TENDON, k->tendon));
    return fail(err, nerr, msg);
  }
  k->length0 = m->tendon_length0[k->tendon];

  return 0;
}

/* The constants of `instance` for model m, from the mjData's cache (re-derived when the
   model or configuration changed). mju_error on a configuration error. */
static const Constants* constants(const mjModel* m, mjData* d, int instance) {
  Cache* c = (Cache*)d->plugin_data[instance];
  if (c->model != m || c->timestep != m->opt.timestep || c->nattr != m->npluginattr
      || c->nplugin != m->nplugin || memcmp(c->attr, m->plugin_attr, m->npluginattr)) {
    char err[500];
    int i;
    free(c->attr);
    free(c->k);
    c->attr = malloc(m->npluginattr > 0 ? m->npluginattr : 1);
    c->k = calloc(m->nplugin, sizeof(Constants));
    if (!c->attr || !c->k) mju_error("wpam_mj.muscle: out of memory");
    memcpy(c->attr, m->plugin_attr, m->npluginattr);
    c->nattr = m->npluginattr;
    c->nplugin = m->nplugin;
    c->model = m;
    c->timestep = m->opt.timestep;
    for (i = 0; i < m->nplugin; i++)
      if (m->plugin[i] == m->plugin[instance] && parse_config(m, i, &c->k[i], 1, err, sizeof(err)))
        mju_error("%s", err);
  }
  return &c->k[instance];
}

/* ---- plugin callbacks ---- */

/* State size; the configuration is validated here, at compile time. */
static int wpam_nstate(const mjModel* m, int instance) {
  Constants k;
  char err[500];
  if (parse_config(m, instance, &k, 0, err, sizeof(err))) mju_error("%s", err);
  return S_COUNT + 2 * k.delay_steps;
}

/* A new mjData: its constants cache; the channels are validated here (mju_error). */
static int wpam_init(const mjModel* m, mjData* d, int instance) {
  Cache* c = calloc(1, sizeof(Cache));
  if (!c) return -1;
  d->plugin_data[instance] = (uintptr_t)c;
  constants(m, d, instance);
  return 0;
}

static void wpam_destroy(mjData* d, int instance) {
  Cache* c = (Cache*)d->plugin_data[instance];
  if (c) {
    free(c->attr);
    free(c->k);
    free(c);
  }
  d->plugin_data[instance] = 0;
}

static void wpam_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  (void)m;
  (void)src;
  wpam_destroy(dest, instance);
  wpam_init(m, dest, instance); /* the copy re-derives its constants on first use */
}

static void wpam_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data,
                       int instance) {
  Constants k;
  char err[500];
  (void)plugin_data;
  if (parse_config(m, instance, &k, 0, err, sizeof(err))) mju_error("%s", err);
  state_reset(&k, plugin_state);
}

/* Write this step's friction level into the tendon's friction row(s). */
static void set_friction_rows(const mjModel* m, mjData* d, int tendon, double friction) {
  int i;
  for (i = 0; i < d->nefc; i++)
    if (d->efc_type[i] == mjCNSTR_FRICTION_TENDON && d->efc_id[i] == tendon)
      d->efc_frictionloss[i] = friction;
}

static void wpam_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  const Constants* k = constants(m, d, instance);
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  const double* ctrl = d->ctrl;
  double pa = k->p[P_PNEUMATICS_ATMOSPHERE];
  double x = k->contraction0 + (k->length0 - d->ten_length[k->tendon]);
  double v = -d->ten_velocity[k->tendon];
  double x_ref = NAN, pi_cmd, po_cmd, pi, po, tension, friction;
  int i;
  (void)capability_bit;

  if (CONTROL_FEEDBACK[k->control]) {
    double po_ff = k->nchannel > 2 ? ctrl[k->channel[2]] : 0.0;
    double integral_next, derivative, e;
    x_ref = ctrl[k->channel[0]];
    pi_cmd = k->nchannel > 1 ? ctrl[k->channel[1]] : pi_feedforward(k, x_ref);
    po_cmd = feedback_output(k, s, x, x_ref, po_ff, &integral_next, &derivative, &e);
    s[S_NEXT_INTEGRAL] = integral_next;
    s[S_NEXT_DERIVATIVE] = derivative;
    s[S_NEXT_E] = e;
  } else {
    pi_cmd = ctrl[k->channel[0]];
    po_cmd = ctrl[k->channel[1]];
  }
  if (s[S_REST_PENDING] != 0.0) plant_rest(k, s, pi_cmd, po_cmd);
  pi = s[S_P_I] - pa;
  po = s[S_P_O] - pa;
  tension = muscle_tension(k, x, pi, po);
  friction = muscle_friction(k, x, pi, po);
  if (!(-1.0 < x && x < 1.0) && s[S_STATUS] == 0.0) s[S_STATUS] = WPAM_FAIL_CONTRACTION;

  s[S_X] = x;
  s[S_VELOCITY] = v;
  s[S_X_REF] = x_ref;
  s[S_PI] = pi;
  s[S_PO] = po;
  s[S_PI_CMD] = pi_cmd;
  s[S_PO_CMD] = po_cmd;
  s[S_TENSION] = tension;
  s[S_FRICTION] = friction;

  d->actuator_force[k->channel[0]] = -tension; /* along the tendon's length */
  for (i = 1; i < k->nchannel; i++) d->actuator_force[k->channel[i]] = 0.0;
  set_friction_rows(m, d, k->tendon, friction);
}

static void wpam_advance(const mjModel* m, mjData* d, int instance) {
  /* compute ran on this model in this step: its constants are current */
  const Cache* c = (const Cache*)d->plugin_data[instance];
  const Constants* k = c->model == m ? &c->k[instance] : constants(m, d, instance);
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  double pa = k->p[P_PNEUMATICS_ATMOSPHERE];
  double x = s[S_X], v = s[S_VELOCITY], set_i, set_o, area, vol;
  int head = (int)s[S_HEAD];

  if (CONTROL_FEEDBACK[k->control]) { /* PoFeedback.update's commit */
    s[S_INTEGRAL] = s[S_NEXT_INTEGRAL];
    s[S_DERIVATIVE] = s[S_NEXT_DERIVATIVE];
    s[S_E_PREV] = s[S_NEXT_E];
    s[S_HAS_PREV] = 1.0;
  }
  s[S_REST_PENDING] = 0.0;
  /* Plant.advance: regulators, then chambers (volumes: pneumatics.chamber_volumes) */
  set_i = regulator_update(k, &s[S_PI_REG], queue_i(s), head, s[S_PI_CMD]);
  set_o = regulator_update(k, &s[S_PO_REG], queue_o(k, s), head, s[S_PO_CMD]);
  if (k->delay_steps) s[S_HEAD] = (head + 1) % k->delay_steps;
  area = geom_area(k, x);
  vol = geom_volume(k, x);
  s[S_P_I] = chamber_step(k, s[S_P_I], k->p[P_PNEUMATICS_INNER_CONDUCTANCE], set_i + pa,
                          vol + k->p[P_PNEUMATICS_TUBE_VOLUME], area, v);
  s[S_P_O] = chamber_step(k, s[S_P_O], k->p[P_PNEUMATICS_OUTER_CONDUCTANCE], set_o + pa,
                          k->bag_volume + k->p[P_PNEUMATICS_TUBE_VOLUME] - vol
                              - k->p[P_MUSCLE_AXIAL_AREA] * x,
                          -(area + k->p[P_MUSCLE_AXIAL_AREA]), v);
  if (!(s[S_P_I] > 0.0 && s[S_P_O] > 0.0) && s[S_STATUS] == 0.0)
    s[S_STATUS] = WPAM_FAIL_PRESSURE;
}

/* 1 when the headers this file was compiled with match the loaded libmujoco. */
int wpam_abi_ok(void) { return mj_version() == mjVERSION_HEADER; }

/* The generated tables' fingerprint, checked by wpam_mj/simulation/plugin.py when it loads us. */
const char* wpam_tables_hash(void) { return WPAM_TABLES_HASH; }

mjPLUGIN_LIB_INIT(wpam_muscle) {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = "wpam_mj.muscle";
  plugin.capabilityflags |= mjPLUGIN_ACTUATOR;
  plugin.nattribute = NATTRIBUTE;
  plugin.attributes = ATTRIBUTES;
  plugin.nstate = wpam_nstate;
  plugin.init = wpam_init;
  plugin.destroy = wpam_destroy;
  plugin.copy = wpam_copy;
  plugin.reset = wpam_reset;
  plugin.compute = wpam_compute;
  plugin.advance = wpam_advance;
  mjp_registerPlugin(&plugin);
}
