/* The configuration of one muscle, once per model: every attribute read (a word, or a
   number within its own range), every rule between quantities checked (the rule table of
   wpam_mj/physics/rules.py, generated into WPAM_RULES), the constants derived by the
   kernel's functions, the input channels bound. A bad configuration gives one line naming
   the value and its allowed range, never a failure on the step path. */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "muscle_plugin.h"

/* columns of WPAM_PARAMS(F) and WPAM_NUMBERS(F): F(NAME, key, unit, lo, hi, lo_open) */
#define WPAM_LO(NAME, key, unit, lo, hi, lo_open) lo,
#define WPAM_HI(NAME, key, unit, lo, hi, lo_open) hi,
#define WPAM_LO_OPEN(NAME, key, unit, lo, hi, lo_open) lo_open,

/* ---- tables from the generated header ---- */

/* The quantities the rules speak of: the parameters (Q_x == P_x), the instance's numbers,
   the time step and the derived quantities (wpam_mj.physics.rules). */
#define AS_Q(NAME, ...) Q_##NAME,
enum { WPAM_PARAMS(AS_Q) WPAM_NUMBERS(AS_Q) Q_TIMESTEP, WPAM_DERIVED(AS_Q) Q_COUNT };
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
const int CONTROL_FEEDBACK[] = {WPAM_CONTROLS(AS_FEEDBACK)};

/* ---- configuration: read, checked against the rules, derived (once per model) ---- */

int find_word(const char* word, const char* const* list, int n) {
  int i;
  for (i = 0; i < n; i++)
    if (!strcmp(word, list[i])) return i;
  return -1;
}

/* A number from the configuration (rules.parse_number): strtod must consume the whole
   value but trailing spaces, a decimal number (no hexadecimal), finite. */
int parse_number(const char* text, double* out) {
  char* end;
  if (strpbrk(text, "xX")) return 0;
  *out = strtod(text, &end);
  if (end == text) return 0;
  while (*end == ' ') end++;
  return *end == '\0' && isfinite(*out);
}

const char* instance_name(const mjModel* m, int instance) {
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
  double n = k->p[P_PNEUMATICS_POLYTROPIC_INDEX];
  double bag = kernel_outer_bag_volume(k->p[P_BRAID_OUTER_BAG_LENGTH],
                                       k->p[P_BRAID_OUTER_BAG_DIAMETER]);
  double x_max = k->max_contraction;
  double v_i = kernel_inner_volume(volume_at(k, 0.0), tube);
  double v_o = kernel_outer_volume(volume_at(k, x_max), x_max, k->p[P_MUSCLE_AXIAL_AREA], bag,
                                   tube);
  *dt_i = kernel_stable_timestep(v_i, k->p[P_PNEUMATICS_INNER_CONDUCTANCE], b, n);
  *dt_o = kernel_stable_timestep(v_o, k->p[P_PNEUMATICS_OUTER_CONDUCTANCE], b, n);
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
int no_friction_row(const mjModel* m, int instance, int tendon, int after, char* err,
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
int derive_for_model(const mjModel* m, int instance, Instance* k, char* err,
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

