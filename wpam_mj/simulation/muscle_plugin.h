/* What the plugin's C files share: the generated tables' enums, one muscle of one mjData
   (Instance), the kernel's geometry at an Instance's constants, the state layout's size,
   and the functions one file offers the others.

     muscle_plugin.c   the step and MuJoCo's callbacks (its opening comment says how the
                       plugin works and how it is built);
     muscle_config.c   the configuration: read, checked against the rules, derived;
     muscle_handles.c  the table of Instances and the handles a copied mjData cannot mistake.

   Everything here is internal to the library (hidden): MuJoCo finds the plugin through the
   registration alone. */

#ifndef WPAM_MUSCLE_PLUGIN_H
#define WPAM_MUSCLE_PLUGIN_H

#include <math.h>
#include <stdint.h>

#include <mujoco/mujoco.h>
#include <mujoco/mjplugin.h>

#include "wpam_plugin_tables.h" /* generated from wpam_mj/physics by wpam_mj/simulation/plugin.py */

#define WPAM_INTERNAL __attribute__((visibility("hidden")))

/* ---- enums from the generated header ---- */

#define AS_PARAM_ENUM(NAME, key, unit, lo, hi, lo_open) P_##NAME,
#define AS_STATE_ENUM(NAME, name) S_##NAME,
#define AS_CONTROL_ENUM(NAME, name, nmin, nmax, feedback) C_##NAME,
enum { WPAM_PARAMS(AS_PARAM_ENUM) P_COUNT };
enum { WPAM_STATE(AS_STATE_ENUM) S_COUNT };
enum { WPAM_CONTROLS(AS_CONTROL_ENUM) C_COUNT };
#define AS_NAME(NAME, key, unit, ...) key,

/* 1 for the control modes with Po feedback, by C_* (WPAM_CONTROLS; muscle_config.c). */
WPAM_INTERNAL extern const int CONTROL_FEEDBACK[];

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

/* ---- the kernel's geometry (wpam_mj/physics/kernel.py) at an Instance's constants ---- */

static inline double in_stroke(const Instance* k, double x) {
  return kernel_in_stroke(x, k->max_contraction);
}

static inline double area_at(const Instance* k, double x) {
  return kernel_area(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq, k->volume_denom,
                     k->max_contraction);
}

static inline double volume_at(const Instance* k, double x) {
  return kernel_volume(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq, k->volume_denom,
                       k->max_contraction);
}

static inline double rubber_at(const Instance* k, double x) {
  return kernel_rubber_force(kernel_diameter(x, k->p[P_BRAID_NATURAL_LENGTH], k->thread_sq,
                                             k->diameter_denom, k->max_contraction),
                             k->p[P_MUSCLE_RUBBER_STIFFNESS], k->p[P_BRAID_NATURAL_DIAMETER]);
}

/* ---- the state of one instance (layout WPAM_STATE) ---- */

static inline int state_size(const Instance* k) { return S_COUNT + 2 * k->delay_steps; }

static inline void set_status(double* s, int bit) {
  s[S_STATUS] = (double)((int)s[S_STATUS] | bit);
}

/* ---- muscle_config.c ---- */

WPAM_INTERNAL int find_word(const char* word, const char* const* list, int n);
WPAM_INTERNAL int parse_number(const char* text, double* out);
WPAM_INTERNAL const char* instance_name(const mjModel* m, int instance);
WPAM_INTERNAL int no_friction_row(const mjModel* m, int instance, int tendon, int after,
                                  char* err, int nerr);
WPAM_INTERNAL int derive_for_model(const mjModel* m, int instance, Instance* k, char* err,
                                   int nerr);

/* ---- muscle_handles.c ---- */

WPAM_INTERNAL Instance* slot(uintptr_t handle);
WPAM_INTERNAL int owned(const Instance* k, const mjData* d, int instance);
WPAM_INTERNAL uintptr_t find_owned(const mjData* d, int instance);
WPAM_INTERNAL uintptr_t new_slot(const mjData* d, int instance, const Instance* k);
WPAM_INTERNAL void free_slot(uintptr_t h);
WPAM_INTERNAL Instance* instance_of(const mjModel* m, mjData* d, int instance, double* s);

#endif /* WPAM_MUSCLE_PLUGIN_H */
