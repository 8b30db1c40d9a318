/* The pneumatic muscle as a MuJoCo actuator plugin: "wpam_mj.muscle".

   The physics is not here: it is wpam_mj/physics/kernel.py, written once, which
   wpam_mj/physics/kernel_codegen.py writes into the generated header as C (kernel_*:
   geometry, force, friction, the Pi feedforward, ISO 6358 flow, the chambers' Euler step,
   the regulators' lag, the Po feedback) and which the Python engine
   (wpam_mj/simulation/engine.py) calls as it is, so the two are bit-identical
   (tests/test_plugin.py). This file holds the configuration, the handle table, the
   callbacks and the state glue around those calls. Every range the configuration must lie
   in is the rule table of wpam_mj/physics/rules.py, generated into WPAM_RULES.

   Built with -ffp-contract=off and without -ffast-math (no fused multiply-adds, no
   reassociation); libm's sqrt, pow, sin, cos, asin, expm1 are the functions Python's floats
   call. min/max follow Python's builtins (py_min, py_max of the generated header).

   One plugin instance is one muscle on one tendon. The actuators that name the instance
   are its input channels in model order (WPAM_CONTROLS; docs/plugin.md): all act on the
   muscle's tendon, the first carries the force. The callbacks, as MuJoCo calls them:
     nstate   (compile) the state size: the named fields and the regulators' dead-time
              queues, fixed for the time step the model compiles with;
     init     (compile and every new mjData) the configuration read, checked against the
              rules and derived once into this mjData's Instance; a bad one fails the
              compile with one line (mju_error: never on the step path);
     compute  (mj_fwdActuation, after the constraint rows are made, before the solve) the
              contraction and its velocity from the tendon, the commands, the Po
              controller's output (nothing committed: compute may run more than once per
              step), the tendon force from the chamber pressures, the friction level into
              this simulation's friction row of the tendon (set_friction_level);
     advance  (after integration, once per step) the controller's state committed, the
              regulators and chambers advanced from the values compute used.
   Everything that changes lives in plugin_state (layout WPAM_STATE). The Instance of an
   mjData holds only what its model and configuration determine, plus where the friction
   row was last step; it is found through a handle that a copied or unpickled mjData
   cannot mistake for its own (instance_of).

   Pressures: *_gauge above the atmosphere, *_abs absolute; SI throughout (m, m/s, Pa, N,
   kg/s, s). */

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>
#include <mujoco/mjplugin.h>

#include "wpam_plugin_tables.h" /* generated from wpam_mj/physics by wpam_mj/simulation/plugin.py */

/* columns of WPAM_PARAMS(F) and WPAM_NUMBERS(F): F(NAME, key, unit, lo, hi, lo_open) */
#define WPAM_LO(NAME, key, unit, lo, hi, lo_open) lo,
#define WPAM_HI(NAME, key, unit, lo, hi, lo_open) hi,
#define WPAM_LO_OPEN(NAME, key, unit, lo, hi, lo_open) lo_open,

/* ---- enums and tables from the generated header ---- */

#define AS_PARAM_ENUM(NAME, key, unit, lo, hi, lo_open) P_##NAME,
#define AS_STATE_ENUM(NAME, name) S_##NAME,
#define AS_CONTROL_ENUM(NAME, name, nmin, nmax, feedback) C_##NAME,
enum { WPAM_PARAMS(AS_PARAM_ENUM) P_COUNT };
enum { WPAM_STATE(AS_STATE_ENUM) S_COUNT };
enum { WPAM_CONTROLS(AS_CONTROL_ENUM) C_COUNT };

/* The quantities the rules speak of: the parameters (Q_x == P_x), the instance's numbers,
   the time step and the derived quantities (wpam_mj.physics.rules). */
#define AS_Q(NAME, ...) Q_##NAME,
enum { WPAM_PARAMS(AS_Q) WPAM_NUMBERS(AS_Q) Q_TIMESTEP, WPAM_DERIVED(AS_Q) Q_COUNT };
#define AS_NAME(NAME, key, unit, ...) key,
#define AS_UNIT(NAME, key, unit, ...) unit,
static const char* const QUANTITY_NAMES[] = {
    WPAM_PARAMS(AS_NAME) WPAM_NUMBERS(AS_NAME) "timestep", WPAM_DERIVED(AS_NAME)};
static const char* const QUANTITY_UNITS[] = {
    WPAM_PARAMS(AS_UNIT) WPAM_NUMBERS(AS_UNIT) "s", WPAM_DERIVED(AS_UNIT)};

#define AS_CONTROL_NAME(NAME, name, ...) #name,
#define AS_NMIN(NAME, name, nmin, nmax, feedback) nmin,
#define AS_NMAX(NAME, name, nmin, nmax, feedback) nmax,
#define AS_FEEDBACK(NAME, name, nmin, nmax, feedback) feedback,
static const char* const CONTROL_NAMES[] = {WPAM_CONTROLS(AS_CONTROL_NAME)};
static const int CONTROL_NMIN[] = {WPAM_CONTROLS(AS_NMIN)};
static const int CONTROL_NMAX[] = {WPAM_CONTROLS(AS_NMAX)};
static const int CONTROL_FEEDBACK[] = {WPAM_CONTROLS(AS_FEEDBACK)};

/* Every configuration attribute: the instance's keys, then every parameter by name. */
static const char* const ATTRIBUTES[] = {WPAM_INSTANCE_KEYS WPAM_PARAMS(AS_NAME)};
#define NATTRIBUTE ((int)(sizeof(ATTRIBUTES) / sizeof(ATTRIBUTES[0])))

/* ---- one muscle of one mjData ---- */

typedef struct {
  /* the configuration, read once */
  double p[P_COUNT];          /* parameters by WPAM_PARAMS, SI */
  int control;                /* C_* */
  int start_at_rest;          /* 1: the first step's commands were held before the run */
  int guided;                 /* 1: end fittings held on one axis (MuscleModel.tendon_force) */
  int outer_chamber;          /* 0: no outer bag for Po to fill (MuscleType.outer_chamber) */
  const char* preset;         /* the preset's name */
  double feedforward_load;    /* load the Pi feedforward holds [N] */
  double contraction0;        /* contraction in the model's reference pose [m] */
  /* what the model determines: the model and options it was derived for */
  const mjModel* model;
  double dt;
  int integrator;
  int refused;                /* 1: this model's options changed after compile: stopped */
  int tendon;                 /* the muscle's tendon id */
  int channel[WPAM_MAX_CHANNELS]; /* actuator ids of the input channels */
  int nchannel;
  double length0;             /* tendon length at which x = contraction0 [m] */
  /* derived once by the kernel's functions of the same names */
  double thread_sq, volume_denom, diameter_denom, max_contraction; /* the braid */
  double lag_alpha;           /* the regulators' lag */
  int delay_steps;            /* the regulators' dead time in steps */
  double bag_volume;          /* outer_bag_volume */
  double pa_per_unit, integral0, kd;  /* the Po feedback's */
  /* this mjData's */
  const mjData* owner;
  int instance;
  int in_use;
  int friction_row;           /* where the tendon's friction row was last step */
} Instance;

/* ---- the kernel's functions (wpam_mj/physics/kernel.py) at an Instance's constants ---- */

static double in_stroke(const Instance* k, double x) {
  return kernel_in_stroke(x, k->max_contraction);
}

static double area_at(const Instance* k, double x) {
  return kernel_area(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq, k->volume_denom,
                     k->max_contraction);
}

static double volume_at(const Instance* k, double x) {
  return kernel_volume(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq, k->volume_denom,
                       k->max_contraction);
}

static double rubber_at(const Instance* k, double x) {
  return kernel_rubber_force(kernel_diameter(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq,
                                             k->diameter_denom, k->max_contraction),
                             k->p[P_MUSCLE_RUBBER_STIFFNESS], k->p[P_BRAID_NATURAL_DIAMETER]);
}

/* The Pi [Pa gauge] that holds x_ref under the feedforward load at Po = po_feedforward on
   the branch feedforward_friction, clipped to the regulator range (control.pi_feedforward). */
static double pi_feedforward(const Instance* k, double x_ref) {
  const double* p = k->p;
  double pi_gauge = kernel_equilibrium_pressure(
      p[P_CONTROLLER_PO_FEEDFORWARD], k->feedforward_load, p[P_CONTROLLER_FEEDFORWARD_FRICTION],
      area_at(k, x_ref), rubber_at(k, x_ref), p[P_MUSCLE_OUTPUT_COEFF],
      p[P_MUSCLE_FRICTION_COEFF], p[P_MUSCLE_FRICTION_CONST], p[P_MUSCLE_AXIAL_AREA]);
  return kernel_clip(pi_gauge, p[P_PNEUMATICS_P_MIN], p[P_PNEUMATICS_P_MAX]);
}

/* A regulator's flow into its chamber at set point `set_gauge` [Pa gauge] through the line of
   conductance `line` (kernel.regulator_flow) [kg/s]. */
static double regulator_flow(const Instance* k, double set_gauge, double chamber_abs,
                             double line) {
  double atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  return kernel_regulator_flow(set_gauge + atmosphere, chamber_abs,
                               k->p[P_PNEUMATICS_SUPPLY_PRESSURE] + atmosphere, atmosphere,
                               line, k->p[P_PNEUMATICS_SUPPLY_VALVE_CONDUCTANCE],
                               k->p[P_PNEUMATICS_EXHAUST_VALVE_CONDUCTANCE],
                               k->p[P_PNEUMATICS_CRITICAL_RATIO]);
}

/* A regulator's step (Regulator.update): the command through the dead time (ring buffer
   `queue`, shared head), then kernel.regulator_set_point. Returns the set point [Pa gauge]. */
static double regulator_update(const Instance* k, double* set_gauge, double* queue,
                               int head, double command) {
  if (k->delay_steps) {
    double held = queue[head];
    queue[head] = command;
    command = held;
  }
  *set_gauge = kernel_regulator_set_point(*set_gauge, command, k->p[P_PNEUMATICS_P_MAX],
                                          k->lag_alpha);
  return *set_gauge;
}

/* Regulator.rest: every command in flight and the set point at a held command. */
static void regulator_rest(const Instance* k, double* set_gauge, double* queue,
                           double command) {
  int i;
  for (i = 0; i < k->delay_steps; i++) queue[i] = command;
  *set_gauge = kernel_regulator_clamp(command, k->p[P_PNEUMATICS_P_MAX]);
}

/* kernel.po_feedback on the committed state s: the Po command, and what advance commits. */
static double feedback_output(const Instance* k, const double* s, double x, double x_ref,
                              double po_ff, double* integral_next, double* derivative,
                              double* e_out) {
  const double* p = k->p;
  double u;
  kernel_po_feedback(x, x_ref, po_ff, s[S_INTEGRAL], s[S_DERIVATIVE], s[S_E_PREV],
                     s[S_HAS_PREV] != 0.0, p[P_CONTROLLER_KP], p[P_CONTROLLER_KI], k->kd,
                     p[P_CONTROLLER_DERIVATIVE_FILTER], k->pa_per_unit, p[P_PNEUMATICS_P_MIN],
                     p[P_CONTROLLER_PO_CAP], k->dt, &u, integral_next, derivative, e_out);
  return u;
}

/* ---- the state of one instance ---- */

static double* queue_i(double* s) { return s + S_COUNT; }
static double* queue_o(const Instance* k, double* s) { return s + S_COUNT + k->delay_steps; }
static int state_size(const Instance* k) { return S_COUNT + 2 * k->delay_steps; }

/* Initial state: vented chambers, empty regulators, controller at its bumpless start. */
static void state_reset(const Instance* k, double* s) {
  int i;
  for (i = 0; i < state_size(k); i++) s[i] = 0.0;
  s[S_X_REF] = NAN;
  s[S_P_I] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_P_O] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_INTEGRAL] = k->integral0;
  s[S_REST_PENDING] = k->start_at_rest;
}

/* Plant.rest: regulators settled on the commands, chambers at their set points. */
static void plant_rest(const Instance* k, double* s, double pi_cmd, double po_cmd) {
  double atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  regulator_rest(k, &s[S_PI_REG], queue_i(s), pi_cmd);
  regulator_rest(k, &s[S_PO_REG], queue_o(k, s), po_cmd);
  s[S_P_I] = s[S_PI_REG] + atmosphere;
  s[S_P_O] = s[S_PO_REG] + atmosphere;
}

/* Once a muscle's state has left its range, or its model changed under it, it stops:
   no force, no advance, until mj_resetData. */
static int stopped(const double* s) {
  return ((int)s[S_STATUS] & (WPAM_STATUS_PRESSURE | WPAM_STATUS_MODEL)) != 0;
}

static void set_status(double* s, int bit) { s[S_STATUS] = (double)((int)s[S_STATUS] | bit); }

/* ---- configuration: read, checked against the rules, derived (once per model) ---- */

static int find_word(const char* word, const char* const* list, int n) {
  int i;
  for (i = 0; i < n; i++)
    if (!strcmp(word, list[i])) return i;
  return -1;
}

/* A number from the configuration (rules.parse_number): strtod must consume the whole
   value but trailing spaces, a decimal number (no hexadecimal), finite. */
static int parse_number(const char* text, double* out) {
  char* end;
  if (strpbrk(text, "xX")) return 0;
  *out = strtod(text, &end);
  if (end == text) return 0;
  while (*end == ' ') end++;
  return *end == '\0' && isfinite(*out);
}

static const char* instance_name(const mjModel* m, int instance) {
  const char* name = mj_id2name(m, mjOBJ_PLUGIN, instance);
  return name ? name : "(unnamed)";
}

/* rules.shown_range and rules.message: the one line of a value outside its range. */
static void shown_range(char* out, int nout, double lo, double hi, int lo_open, int hi_open,
                        const char* unit) {
  snprintf(out, nout, "%c%.6g, %.6g%c%s%s", lo_open || lo == -INFINITY ? '(' : '[', lo, hi,
           hi_open || hi == INFINITY ? ')' : ']', strcmp(unit, "1") ? " " : "",
           strcmp(unit, "1") ? unit : "");
}

static void range_message(char* err, int nerr, const char* name, int q, double value,
                          double lo, double hi, int lo_open, int hi_open, const char* why) {
  const char* unit = QUANTITY_UNITS[q];
  char range[160];
  shown_range(range, sizeof(range), lo, hi, lo_open, hi_open, unit);
  snprintf(err, nerr, "wpam_mj.muscle instance '%s': %s = %.6g%s%s is outside the allowed "
           "range %s%s%s%s", name, QUANTITY_NAMES[q], value, strcmp(unit, "1") ? " " : "",
           strcmp(unit, "1") ? unit : "", range, why[0] ? " (" : "", why, why[0] ? ")" : "");
}

/* A word from the configuration, one of `list` (or the first when absent). */
static int read_word(const mjModel* m, int instance, const char* key, const char* const* list,
                     int n, const char* allowed, int* out, char* err, int nerr) {
  const char* text = mj_getPluginConfig(m, instance, key);
  *out = text && text[0] ? find_word(text, list, n) : 0;
  if (*out < 0) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': %s = '%s' is not one of: %s",
             instance_name(m, instance), key, text, allowed);
    return -1;
  }
  return 0;
}

/* A number of the configuration into q[index] (the default when absent), within its own
   range [lo, hi] (open below when lo_open). */
static int read_number(const mjModel* m, int instance, int index, double lo, double hi,
                       int lo_open, double* q, char* err, int nerr) {
  const char* text = mj_getPluginConfig(m, instance, QUANTITY_NAMES[index]);
  char range[160];
  double value;
  if (!text || !text[0]) return 0; /* MuJoCo keeps an empty value as none */
  if (!parse_number(text, &value)) {
    shown_range(range, sizeof(range), lo, hi, lo_open, 0, QUANTITY_UNITS[index]);
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': %s = '%s' is not a number; "
             "allowed: %s", instance_name(m, instance), QUANTITY_NAMES[index], text, range);
    return -1;
  }
  if (!(lo_open ? value > lo : value >= lo) || !(value <= hi)) {
    range_message(err, nerr, instance_name(m, instance), index, value, lo, hi, lo_open, 0,
                  "");
    return -1;
  }
  q[index] = value;
  return 0;
}

/* The braid's constants into k (kernel.py's functions of the same names). */
static void derive_geometry(Instance* k) {
  double angle = k->p[P_BRAID_BRAID_ANGLE], L0 = k->p[P_BRAID_NATURAL_LENGTH];
  double D0 = k->p[P_BRAID_NATURAL_DIAMETER];
  double n = kernel_turns(L0, angle, D0);
  k->max_contraction = kernel_max_contraction(L0, angle, D0, k->p[P_BRAID_MAX_DIAMETER]);
  k->thread_sq = kernel_thread_square(L0, angle);
  k->volume_denom = kernel_volume_denominator(n);
  k->diameter_denom = kernel_diameter_denominator(n);
}

/* pneumatics.stable_timesteps: the longest stable step of each chamber's update [s]. */
static void stable_timesteps(const Instance* k, double* dt_i, double* dt_o) {
  double b = k->p[P_PNEUMATICS_CRITICAL_RATIO], tube = k->p[P_PNEUMATICS_TUBE_VOLUME];
  double bag = kernel_outer_bag_volume(k->p[P_BRAID_OUTER_BAG_LENGTH],
                                       k->p[P_BRAID_OUTER_BAG_DIAMETER]);
  double x_max = k->max_contraction;
  double v_i = kernel_inner_volume(volume_at(k, 0.0), tube);
  double v_o = kernel_outer_volume(volume_at(k, x_max), x_max, k->p[P_MUSCLE_AXIAL_AREA], bag,
                                   tube);
  *dt_i = kernel_stable_timestep(v_i, k->p[P_PNEUMATICS_INNER_CONDUCTANCE], b);
  *dt_o = kernel_stable_timestep(v_o, k->p[P_PNEUMATICS_OUTER_CONDUCTANCE], b);
}

/* The derived quantities of the rules (rules.DERIVED), into q; k's geometry derived. */
static void derive_quantities(Instance* k, double* q) {
  double d_bag = q[Q_BRAID_OUTER_BAG_DIAMETER];
  memcpy(k->p, q, sizeof(k->p));
  derive_geometry(k);
  q[Q_LOCKING_ANGLE] = kernel_locking_angle(q[Q_BRAID_NATURAL_DIAMETER],
                                            q[Q_BRAID_MAX_DIAMETER]);
  q[Q_BAG_SECTION] = kernel_bag_section(d_bag);
  q[Q_MAX_CONTRACTION] = k->max_contraction;
  stable_timesteps(k, &q[Q_INNER_STABLE_TIMESTEP], &q[Q_OUTER_STABLE_TIMESTEP]);
  q[Q_SHORTEST_TIMESTEP] = q[Q_PNEUMATICS_DEAD_TIME] / WPAM_MAX_QUEUE_STEPS;
}

/* rules.check over WPAM_RULES: the first rule that fails (NaN never holds). */
static int check_rules(const mjModel* m, int instance, const double* q, char* err, int nerr) {
#define Q(NAME) q[Q_##NAME]
#define CHECK_RULE(SUBJECT, LO, LO_OPEN, HI, HI_OPEN, WHY)                                   \
  {                                                                                          \
    double v = q[Q_##SUBJECT], lo = LO, hi = HI;                                             \
    if (!(LO_OPEN ? v > lo : v >= lo) || !(HI_OPEN ? v < hi : v <= hi)) {                    \
      range_message(err, nerr, instance_name(m, instance), Q_##SUBJECT, v, lo, hi, LO_OPEN,  \
                    HI_OPEN, WHY);                                                           \
      return -1;                                                                             \
    }                                                                                        \
  }
  WPAM_RULES(CHECK_RULE)
#undef CHECK_RULE
#undef Q
  return 0;
}

/* The constants the Python engine's pieces derive from the parameters and dt. */
static void derive_constants(Instance* k) {
  double tau = k->p[P_PNEUMATICS_TIME_CONSTANT];
  k->delay_steps = (int)nearbyint(k->p[P_PNEUMATICS_DEAD_TIME] / k->dt); /* half-even */
  k->lag_alpha = kernel_lag_alpha(k->dt, tau);
  k->bag_volume = kernel_outer_bag_volume(k->p[P_BRAID_OUTER_BAG_LENGTH],
                                          k->p[P_BRAID_OUTER_BAG_DIAMETER]);
  k->pa_per_unit = k->p[P_CONTROLLER_COMMAND_SCALE] * WPAM_MPA;
  k->kd = k->control == C_PID ? k->p[P_CONTROLLER_KD] : 0.0;
  k->integral0 = !CONTROL_FEEDBACK[k->control] ? 0.0
                 : kernel_initial_integral(k->p[P_CONTROLLER_PO_FEEDFORWARD],
                                           k->p[P_CONTROLLER_KI], k->pa_per_unit);
}

/* The configuration of `instance` for model m at its time step into k: every attribute
   read (engine.InstanceConfig.from_config), every rule checked, the constants derived.
   Returns 0, or -1 with the one line in err. Never raises: the step path calls it too. */
static int read_config(const mjModel* m, int instance, Instance* k, char* err, int nerr) {
  static const double PRESET_DEFAULTS[WPAM_NPRESET][P_COUNT] = WPAM_PRESET_DEFAULTS;
  static const double LO[] = {WPAM_PARAMS(WPAM_LO) WPAM_NUMBERS(WPAM_LO)};
  static const double HI[] = {WPAM_PARAMS(WPAM_HI) WPAM_NUMBERS(WPAM_HI)};
  static const int LO_OPEN[] = {WPAM_PARAMS(WPAM_LO_OPEN) WPAM_NUMBERS(WPAM_LO_OPEN)};
  static const char* const PRESETS[] = {WPAM_PRESETS};
  static const int PRESET_OUTER[] = {WPAM_PRESET_OUTER}; /* MuscleType.outer_chamber */
  static const char* const START[] = {"vented", "rest"};
  static const char* const FITTINGS[] = {"free", "guided"};
  double q[Q_COUNT];
  int i, preset;
  memset(k, 0, sizeof(*k));
  k->dt = m->opt.timestep;
  k->integrator = m->opt.integrator;
  if (read_word(m, instance, "preset", PRESETS, WPAM_NPRESET, WPAM_PRESET_LIST, &preset,
                err, nerr)
      || read_word(m, instance, "control", CONTROL_NAMES, C_COUNT, WPAM_CONTROL_LIST,
                   &k->control, err, nerr)
      || read_word(m, instance, "start", START, 2, "vented, rest", &k->start_at_rest, err,
                   nerr)
      || read_word(m, instance, "end_fittings", FITTINGS, 2, "free, guided", &k->guided, err,
                   nerr))
    return -1;
  for (i = 0; i < P_COUNT; i++) q[i] = PRESET_DEFAULTS[preset][i];
  q[Q_FEEDFORWARD_LOAD] = 0.0;
  q[Q_CONTRACTION0] = 0.0;
  q[Q_TIMESTEP] = k->dt;
  for (i = 0; i < Q_TIMESTEP; i++)
    if (read_number(m, instance, i, LO[i], HI[i], LO_OPEN[i], q, err, nerr)) return -1;
  if (CONTROL_FEEDBACK[k->control] && !PRESET_OUTER[preset]) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': preset '%s' has no outer chamber for "
             "Po feedback (control = '%s'); use control = 'open'", instance_name(m, instance),
             PRESETS[preset], CONTROL_NAMES[k->control]);
    return -1;
  }
  derive_quantities(k, q);
  if (check_rules(m, instance, q, err, nerr)) return -1;
  if (k->integrator == mjINT_RK4) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': the RK4 integrator evaluates each "
             "step four times; use Euler, implicit or implicitfast (the pneumatics advance "
             "once per step)", instance_name(m, instance));
    return -1;
  }
  k->feedforward_load = q[Q_FEEDFORWARD_LOAD];
  k->contraction0 = q[Q_CONTRACTION0];
  k->outer_chamber = PRESET_OUTER[preset];
  k->preset = PRESETS[preset];
  derive_constants(k);
  return 0;
}

/* 1, with the line in err, when MuJoCo makes no friction row for the muscle's tendon, the
   row its dry friction acts through (set_friction_level): the tendon's frictionloss is not
   positive, or MuJoCo's constraint or frictionloss flag is disabled. At compile
   (after = 0) the model is refused; after it (a model field or flag edited, as MuJoCo's
   viewer allows) the muscle stops, as for its time step (current_for). */
static int no_friction_row(const mjModel* m, int instance, int tendon, int after, char* err,
                           int nerr) {
  const char* name = instance_name(m, instance);
  const char* stop = "; the muscle stops until it is changed back and the data reset";
  int flags = m->opt.disableflags;
  if (m->tendon_frictionloss[tendon] <= 0.0) {
    if (after)
      snprintf(err, nerr, "wpam_mj.muscle instance '%s': tendon '%s' frictionloss = %.6g after "
               "the model compiled; it needs a positive one (any value; the plugin sets the "
               "level every step)%s", name, mj_id2name(m, mjOBJ_TENDON, tendon),
               m->tendon_frictionloss[tendon], stop);
    else
      snprintf(err, nerr, "wpam_mj.muscle instance '%s': tendon '%s' needs a positive "
               "frictionloss (any value; the plugin sets the level every step)", name,
               mj_id2name(m, mjOBJ_TENDON, tendon));
    return 1;
  }
  if (flags & (mjDSBL_CONSTRAINT | mjDSBL_FRICTIONLOSS)) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': MuJoCo's %s flag is disabled%s, so no "
             "friction row carries the muscle's dry friction%s", name,
             flags & mjDSBL_CONSTRAINT ? "constraint" : "frictionloss",
             after ? " after the model compiled" : "", after ? stop : "; enable it");
    return 1;
  }
  return 0;
}

/* The input channels: every actuator naming the instance, in model order, all on the
   muscle's tendon, which no other muscle pulls and whose friction row MuJoCo makes. A
   muscle without an outer chamber takes no Po channel (Control.channels_for). */
static int bind_channels(const mjModel* m, int instance, Instance* k, char* err, int nerr) {
  static const int NMAX_BARE[] = {WPAM_CONTROL_NMAX_BARE};
  const char* name = instance_name(m, instance);
  int nmin = CONTROL_NMIN[k->control], nmax = CONTROL_NMAX[k->control];
  int i, j;
  k->nchannel = 0;
  for (i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    if (k->nchannel < WPAM_MAX_CHANNELS) k->channel[k->nchannel] = i;
    k->nchannel++;
  }
  if (!k->outer_chamber) {
    nmax = NMAX_BARE[k->control];
    nmin = nmax < nmin ? nmax : nmin;
    if (k->nchannel > nmax && nmax < CONTROL_NMAX[k->control]) {
      const char* extra = mj_id2name(m, mjOBJ_ACTUATOR, k->channel[nmax]);
      snprintf(err, nerr, "wpam_mj.muscle instance '%s': preset '%s' has no outer chamber, "
               "so no Po channel: control = '%s' takes at most %d actuator(s) on it, %d name "
               "the instance; remove actuator '%s'", name, k->preset,
               CONTROL_NAMES[k->control], nmax, k->nchannel, extra ? extra : "(unnamed)");
      return -1;
    }
  }
  if (k->nchannel < nmin || k->nchannel > nmax) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': control = '%s' takes %d to %d "
             "actuators (input channels), %d name the instance", name,
             CONTROL_NAMES[k->control], nmin, nmax, k->nchannel);
    return -1;
  }
  if (m->actuator_trntype[k->channel[0]] != mjTRN_TENDON) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': its first actuator must act on a "
             "tendon (the muscle)", name);
    return -1;
  }
  k->tendon = m->actuator_trnid[2 * k->channel[0]];
  for (i = 1; i < k->nchannel; i++) {
    int a = k->channel[i];
    if (m->actuator_trntype[a] != mjTRN_TENDON || m->actuator_trnid[2 * a] != k->tendon) {
      snprintf(err, nerr, "wpam_mj.muscle instance '%s': actuator '%s' does not act on the "
               "muscle's tendon '%s'; every input channel names the muscle's tendon", name,
               mj_id2name(m, mjOBJ_ACTUATOR, a), mj_id2name(m, mjOBJ_TENDON, k->tendon));
      return -1;
    }
  }
  for (j = 0; j < m->nplugin; j++) { /* the first channel of every other muscle */
    if (j == instance || m->plugin[j] != m->plugin[instance]) continue;
    for (i = 0; i < m->nu && m->actuator_plugin[i] != j; i++) continue;
    if (i < m->nu && m->actuator_trntype[i] == mjTRN_TENDON
        && m->actuator_trnid[2 * i] == k->tendon) {
      snprintf(err, nerr, "wpam_mj.muscle instances '%s' and '%s' both pull tendon '%s'; "
               "one muscle per tendon", instance_name(m, j < instance ? j : instance),
               instance_name(m, j < instance ? instance : j),
               mj_id2name(m, mjOBJ_TENDON, k->tendon));
      return -1;
    }
  }
  if (no_friction_row(m, instance, k->tendon, 0, err, nerr)) return -1;
  k->length0 = m->tendon_length0[k->tendon];
  return 0;
}

/* Everything the model determines, read for model m: its configuration and channels,
   and a state layout that fits the state MuJoCo sized when the model compiled. */
static int derive_for_model(const mjModel* m, int instance, Instance* k, char* err,
                            int nerr) {
  if (read_config(m, instance, k, err, nerr) || bind_channels(m, instance, k, err, nerr))
    return -1;
  if (state_size(k) != m->plugin_statenum[instance]) {
    snprintf(err, nerr, "wpam_mj.muscle instance '%s': timestep = %.6g s needs dead-time "
             "queues of %d steps, but the model compiled with %d; the time step is fixed when "
             "the model compiles", instance_name(m, instance), k->dt, k->delay_steps,
             (m->plugin_statenum[instance] - S_COUNT) / 2);
    return -1;
  }
  k->model = m;
  k->friction_row = 0;
  return 0;
}

/* ---- the Instances of every mjData: handles a copied mjData cannot mistake ----

   MuJoCo keeps one uintptr_t per instance in d->plugin_data and copies it raw when an
   MjData is pickled, into a data that is not the one it was made for (or into another
   process, where it means nothing). So plugin_data holds a handle, index + 1 into this
   library's table of Instances, never a pointer: a handle is looked up, bounds-checked
   and its Instance's owner compared with d before anything is read through it. A data
   holding another's handle (a pickled copy) finds or makes its own. The table grows in
   chunks that never move, so steps on other threads read it without a lock. */

#define CHUNK_SLOTS 64
#define MAX_CHUNKS 16384
static Instance* chunks[MAX_CHUNKS];
static atomic_int nslot;  /* slots handed out: handles 1 .. nslot are valid indices */
static pthread_mutex_t table_lock = PTHREAD_MUTEX_INITIALIZER;

static Instance* slot(uintptr_t handle) {
  uintptr_t i = handle - 1;
  if (handle == 0 || handle > (uintptr_t)atomic_load(&nslot)) return NULL;
  return &chunks[i / CHUNK_SLOTS][i % CHUNK_SLOTS];
}

static int owned(const Instance* k, const mjData* d, int instance) {
  return k && k->in_use && k->owner == d && k->instance == instance;
}

/* The handle of d's Instance of `instance`, 0 if it has none. */
static uintptr_t find_owned(const mjData* d, int instance) {
  uintptr_t h, n = (uintptr_t)atomic_load(&nslot);
  for (h = 1; h <= n; h++)
    if (owned(slot(h), d, instance)) return h;
  return 0;
}

/* A new Instance owned by (d, instance) holding *k: a freed slot, or one appended (its
   chunk allocated first, then published by nslot); 0 when memory runs out. */
static uintptr_t new_slot(const mjData* d, int instance, const Instance* k) {
  uintptr_t h, n;
  Instance* fresh;
  pthread_mutex_lock(&table_lock);
  n = (uintptr_t)atomic_load(&nslot);
  for (h = 1; h <= n && slot(h)->in_use; h++) continue;
  if (h > n) {
    uintptr_t chunk = n / CHUNK_SLOTS;
    if (chunk < MAX_CHUNKS && !chunks[chunk])
      chunks[chunk] = calloc(CHUNK_SLOTS, sizeof(Instance));
    if (chunk >= MAX_CHUNKS || !chunks[chunk]) {
      pthread_mutex_unlock(&table_lock);
      return 0;
    }
    atomic_store(&nslot, (int)h);
  }
  fresh = slot(h);
  *fresh = *k;
  fresh->owner = d;
  fresh->instance = instance;
  fresh->in_use = 1;
  pthread_mutex_unlock(&table_lock);
  return h;
}

static void free_slot(uintptr_t h) {
  pthread_mutex_lock(&table_lock);
  slot(h)->in_use = 0;
  slot(h)->owner = NULL;
  pthread_mutex_unlock(&table_lock);
}

/* The one line of why a muscle stops stepping, as a MuJoCo warning (once per cause). */
static void refuse(Instance* k, double* s, const char* err) {
  if (!k->refused) mju_warning("%s", err);
  k->refused = 1;
  set_status(s, WPAM_STATUS_MODEL);
}

/* d's own Instance of `instance`. A pickled copy holds another data's handle: it finds the
   Instance its own init made, or makes one. NULL (status set) if it cannot. */
static Instance* own_instance(const mjModel* m, mjData* d, int instance, double* s) {
  Instance* k = slot(d->plugin_data[instance]);
  Instance fresh;
  char err[600];
  uintptr_t h;
  if (owned(k, d, instance)) return k;
  h = find_owned(d, instance);
  if (!h) {
    if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
      if (!((int)s[S_STATUS] & WPAM_STATUS_MODEL)) mju_warning("%s", err);
      set_status(s, WPAM_STATUS_MODEL);
      return NULL;
    }
    h = new_slot(d, instance, &fresh);
    if (!h) return NULL;
  }
  d->plugin_data[instance] = h;
  return slot(h);
}

/* Whether k is current for model m and its options: the same model with its time step or
   integrator edited after compile (MuJoCo's viewer allows it), or without the muscle's
   friction row (no_friction_row), is refused; another model of the same state layout
   (mujoco.batch's set_models) is derived afresh. */
static int current_for(const mjModel* m, int instance, Instance* k, double* s) {
  static const char* const INTEGRATORS[] = {WPAM_INTEGRATORS};
  const int nintegrator = (int)(sizeof(INTEGRATORS) / sizeof(INTEGRATORS[0]));
  int integrator = m->opt.integrator;
  Instance fresh;
  char err[600];
  int options = k->dt == m->opt.timestep && k->integrator == integrator;
  if (k->model == m && options && !no_friction_row(m, instance, k->tendon, 1, err,
                                                   sizeof(err))) {
    k->refused = 0; /* (changed back: the muscle steps again after mj_resetData) */
    return 1;
  }
  if (k->model == m && options) { /* err: why the friction row is missing */
    refuse(k, s, err);
    return 0;
  }
  if (k->model == m) {
    snprintf(err, sizeof(err), "wpam_mj.muscle instance '%s': the %s changed after the model "
             "compiled (timestep %.6g s, integrator %s); the muscle stops until it is changed "
             "back or the model recompiled", instance_name(m, instance),
             k->dt != m->opt.timestep ? "timestep" : "integrator", m->opt.timestep,
             integrator >= 0 && integrator < nintegrator ? INTEGRATORS[integrator] : "unknown");
    refuse(k, s, err);
    return 0;
  }
  if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
    refuse(k, s, err);
    return 0;
  }
  fresh.owner = k->owner;
  fresh.instance = k->instance;
  fresh.in_use = 1;
  *k = fresh;
  return 1;
}

/* d's Instance of `instance`, current for model m; NULL when the muscle cannot step. */
static Instance* instance_of(const mjModel* m, mjData* d, int instance, double* s) {
  Instance* k = own_instance(m, d, instance, s);
  return k && current_for(m, instance, k, s) ? k : NULL;
}

/* ---- the step ---- */

/* The commands of this step from the input channels: each clamped to its actuator's
   ctrlrange where limited (as MuJoCo does for its own actuators); a non-finite one, which
   MuJoCo warns about (mjWARN_BADCTRL), replaced by that channel's last finite value
   (held in the state, 0 at the start); the target held to the stroke. */
static void read_commands(const mjModel* m, const mjData* d, const Instance* k, double* s,
                          double* command) {
  int i;
  for (i = 0; i < k->nchannel; i++) {
    int a = k->channel[i];
    double c = d->ctrl[a];
    if (m->actuator_ctrllimited[a])
      c = py_min(py_max(c, m->actuator_ctrlrange[2 * a]), m->actuator_ctrlrange[2 * a + 1]);
    if (isfinite(c))
      s[S_INPUT0 + i] = c;
    command[i] = s[S_INPUT0 + i];
  }
  if (CONTROL_FEEDBACK[k->control]) command[0] = in_stroke(k, command[0]);
}

/* The friction level [N] of this step into this simulation's friction row of the muscle's
   tendon: the plugin's one write into MuJoCo's constraint data.

   MuJoCo makes a friction row for a tendon whose model frictionloss is positive
   (efc_type mjCNSTR_FRICTION_TENDON, efc_id the tendon) in mj_makeConstraint, and reads
   efc_frictionloss in the constraint solve; mj_fwdActuation, which calls compute, runs
   between the two (MuJoCo 3.x mj_forward: ... mj_makeConstraint, ..., mj_fwdActuation,
   mj_fwdAcceleration, mj_fwdConstraint). So the level written here is the one the solver
   (and the no-slip solver) holds the tendon with this step, for this mjData alone; the
   model's tendon_frictionloss, shared by every simulation of a batch, stays untouched.
   tests/test_plugin.py fails if that order changes. The row keeps its place while the
   constraints before it do; it is looked up again when it moved. */
static void set_friction_level(mjData* d, Instance* k, double level) {
  int row = k->friction_row;
  if (!(row < d->nefc && d->efc_type[row] == mjCNSTR_FRICTION_TENDON
        && d->efc_id[row] == k->tendon)) {
    for (row = 0; row < d->nefc; row++)
      if (d->efc_type[row] == mjCNSTR_FRICTION_TENDON && d->efc_id[row] == k->tendon) break;
    if (row == d->nefc) return;
    k->friction_row = row;
  }
  d->efc_frictionloss[row] = level;
}

/* No force from a muscle that does not step (its friction row keeps the model's level). */
static void no_force(const mjModel* m, mjData* d, int instance) {
  int i;
  for (i = 0; i < m->nu; i++)
    if (m->actuator_plugin[i] == instance) d->actuator_force[i] = 0.0;
}

/* ---- plugin callbacks ---- */

/* The state size: the named fields and two dead-time queues of round(dead_time / timestep)
   steps at the time step the model compiles with (checked in full by init). */
static int wpam_nstate(const mjModel* m, int instance) {
  double dead_time = 0.0, dt = m->opt.timestep;
  const char* text = mj_getPluginConfig(m, instance, "pneumatics.dead_time");
  static const double PRESET_DEFAULTS[WPAM_NPRESET][P_COUNT] = WPAM_PRESET_DEFAULTS;
  static const char* const PRESETS[] = {WPAM_PRESETS};
  const char* preset_name = mj_getPluginConfig(m, instance, "preset");
  int preset = preset_name ? find_word(preset_name, PRESETS, WPAM_NPRESET) : 0;
  dead_time = PRESET_DEFAULTS[preset > 0 ? preset : 0][P_PNEUMATICS_DEAD_TIME];
  if (text && text[0] && !parse_number(text, &dead_time)) dead_time = 0.0;
  if (!(dt > 0.0) || !(dead_time >= 0.0) || !(dead_time / dt <= WPAM_MAX_QUEUE_STEPS))
    return S_COUNT; /* init refuses the configuration */
  return S_COUNT + 2 * (int)nearbyint(dead_time / dt);
}

/* A new mjData: the instance's configuration read and checked once, into its Instance. */
static int wpam_init(const mjModel* m, mjData* d, int instance) {
  Instance k;
  char err[600];
  uintptr_t h;
  if (derive_for_model(m, instance, &k, err, sizeof(err))) mju_error("%s", err);
  h = new_slot(d, instance, &k);
  if (!h) return -1;
  d->plugin_data[instance] = h;
  return 0;
}

/* Frees d's own Instance, never another data's whose handle a copy holds. */
static void wpam_destroy(mjData* d, int instance) {
  uintptr_t h = d->plugin_data[instance];
  if (!owned(slot(h), d, instance)) h = find_owned(d, instance);
  if (h) free_slot(h);
  d->plugin_data[instance] = 0;
}

/* mj_copyData: dest keeps its own Instance (MuJoCo restores dest's plugin_data); it holds
   what the model determines, which instance_of re-derives if dest steps another model. */
static void wpam_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  (void)dest;
  (void)m;
  (void)src;
  (void)instance;
}

/* mj_resetData: the initial state from the Instance a handle names (any data's: what the
   model determines is the same), or read afresh; never past the state MuJoCo sized. */
static void wpam_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data,
                       int instance) {
  const Instance* k = slot((uintptr_t)plugin_data);
  Instance fresh;
  char err[600];
  int i;
  if (!(k && k->in_use && k->model == m && k->instance == instance
        && state_size(k) == m->plugin_statenum[instance])) {
    if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
      for (i = 0; i < m->plugin_statenum[instance]; i++) plugin_state[i] = 0.0;
      plugin_state[S_STATUS] = WPAM_STATUS_MODEL;
      return;
    }
    k = &fresh;
  }
  state_reset(k, plugin_state);
}

/* STATUS_STROKE, and the first time since the data's reset one MuJoCo warning naming the
   tendon range that holds the muscle in its stroke (plugin.tendon_range). */
static void left_stroke(const mjModel* m, int instance, const Instance* k, double* s,
                        double x) {
  double natural = k->length0 + k->contraction0; /* the tendon's length at x = 0 */
  if (!((int)s[S_STATUS] & WPAM_STATUS_STROKE))
    mju_warning("wpam_mj.muscle instance '%s': contraction x = %.6g m left the stroke [0, "
                "%.6g] m by more than %.6g m (status %d); limit its tendon from the full bag "
                "to the natural length: range=\"%.6g %.6g\" (plugin.tendon_range)",
                instance_name(m, instance), x, k->max_contraction, WPAM_STROKE_TOLERANCE,
                WPAM_STATUS_STROKE, natural - k->max_contraction, natural);
  set_status(s, WPAM_STATUS_STROKE);
}

static void wpam_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  Instance* k = instance_of(m, d, instance, s);
  double command[WPAM_MAX_CHANNELS] = {0.0};
  double atmosphere, x, v, x_ref = NAN, pi_cmd, po_cmd, pi_gauge, po_gauge, area, force;
  double friction;
  int i;
  (void)capability_bit;
  if (!k || stopped(s)) {
    no_force(m, d, instance);
    return;
  }
  atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  x = k->contraction0 + (k->length0 - d->ten_length[k->tendon]);
  v = -d->ten_velocity[k->tendon];
  read_commands(m, d, k, s, command);
  if (CONTROL_FEEDBACK[k->control]) {
    double po_ff = k->nchannel > 2 ? command[2] : 0.0;
    double integral_next, derivative, e;
    x_ref = command[0];
    pi_cmd = k->nchannel > 1 ? command[1] : pi_feedforward(k, x_ref);
    po_cmd = feedback_output(k, s, x, x_ref, po_ff, &integral_next, &derivative, &e);
    s[S_NEXT_INTEGRAL] = integral_next;
    s[S_NEXT_DERIVATIVE] = derivative;
    s[S_NEXT_E] = e;
  } else {
    pi_cmd = command[0];
    po_cmd = command[1];
  }
  if (s[S_REST_PENDING] != 0.0) plant_rest(k, s, pi_cmd, po_cmd);
  pi_gauge = s[S_P_I] - atmosphere;
  po_gauge = s[S_P_O] - atmosphere;
  area = area_at(k, x);
  force = kernel_tendon_force(pi_gauge, po_gauge, area, rubber_at(k, x),
                              k->p[P_MUSCLE_OUTPUT_COEFF], k->p[P_MUSCLE_AXIAL_AREA], k->guided);
  friction = kernel_friction_level(pi_gauge, po_gauge, area, k->p[P_MUSCLE_FRICTION_COEFF],
                                   k->p[P_MUSCLE_FRICTION_CONST]);
  if (!(-WPAM_STROKE_TOLERANCE <= x && x <= k->max_contraction + WPAM_STROKE_TOLERANCE))
    left_stroke(m, instance, k, s, x);
  if (!isfinite(x)) { /* MuJoCo's state is already bad: add nothing to it */
    force = 0.0;
    friction = k->p[P_MUSCLE_FRICTION_CONST];
  }

  s[S_X] = x;
  s[S_VELOCITY] = v;
  s[S_X_REF] = x_ref;
  s[S_PI] = pi_gauge;
  s[S_PO] = po_gauge;
  s[S_PI_CMD] = pi_cmd;
  s[S_PO_CMD] = po_cmd;
  s[S_TENSION] = force;
  s[S_FRICTION] = friction;

  d->actuator_force[k->channel[0]] = -force; /* along the tendon's length */
  for (i = 1; i < k->nchannel; i++) d->actuator_force[k->channel[i]] = 0.0;
  set_friction_level(d, k, friction);
}

static void wpam_advance(const mjModel* m, mjData* d, int instance) {
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  Instance* k = instance_of(m, d, instance, s);
  double atmosphere, x, set_i, set_o, area, vol, v, m_i, m_o;
  int head;
  if (!k || stopped(s)) return;
  atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  head = (int)s[S_HEAD];
  if (CONTROL_FEEDBACK[k->control]) { /* PoFeedback.update's commit */
    s[S_INTEGRAL] = s[S_NEXT_INTEGRAL];
    s[S_DERIVATIVE] = s[S_NEXT_DERIVATIVE];
    s[S_E_PREV] = s[S_NEXT_E];
    s[S_HAS_PREV] = 1.0;
  }
  s[S_REST_PENDING] = 0.0;
  /* Plant.step: regulators, then chambers (volumes held to the stroke) */
  set_i = regulator_update(k, &s[S_PI_REG], queue_i(s), head, s[S_PI_CMD]);
  set_o = regulator_update(k, &s[S_PO_REG], queue_o(k, s), head, s[S_PO_CMD]);
  if (k->delay_steps) s[S_HEAD] = (head + 1) % k->delay_steps;
  v = s[S_VELOCITY];
  x = in_stroke(k, s[S_X]);
  area = area_at(k, x);
  vol = volume_at(k, x);
  m_i = regulator_flow(k, set_i, s[S_P_I], k->p[P_PNEUMATICS_INNER_CONDUCTANCE]);
  m_o = regulator_flow(k, set_o, s[S_P_O], k->p[P_PNEUMATICS_OUTER_CONDUCTANCE]);
  s[S_P_I] = kernel_chamber_step(s[S_P_I], m_i,
                                 kernel_inner_volume(vol, k->p[P_PNEUMATICS_TUBE_VOLUME]),
                                 area, v, k->dt);
  /* no outer bag (rlam, mckibben): the atmosphere, exactly */
  s[S_P_O] = kernel_outer_chamber_step(k->outer_chamber, s[S_P_O], m_o, vol, x, area,
                                       k->p[P_MUSCLE_AXIAL_AREA], k->bag_volume,
                                       k->p[P_PNEUMATICS_TUBE_VOLUME], v, k->dt, atmosphere);
  if (!(s[S_P_I] > 0.0 && s[S_P_O] > 0.0 && isfinite(s[S_P_I]) && isfinite(s[S_P_O])))
    set_status(s, WPAM_STATUS_PRESSURE);
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
