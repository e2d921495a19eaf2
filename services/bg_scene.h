/*
 * bg_scene — scene files: what to deform, how, and how to solve it.
 *
 * A scene is a JSON object (documented in README.md, "Scene format"). The
 * parser resolves it fully: it loads or generates the mesh, converts the
 * material to (mu, lambda), selects handle vertices and computes their
 * prescribed positions, builds the initial and reference positions. The
 * result is a plain record the solvers read directly.
 *
 * Errors name the scene file and the field path ("bar.json: handles[1]
 * .transform.rotate.axis: expected 3 numbers"), reject unknown keys, wrong
 * types, NaN/Inf, negative or zero sizes, and anything out of range.
 */
#ifndef BG_SCENE_H
#define BG_SCENE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_mesh_io.h"

/* Scene files larger than this are refused. */
#define BG_SCENE_MAX_BYTES ((size_t)16 << 20)
/* Handles a scene may have: each one's selection scans every vertex, so
 * without a cap a 16 MB scene of tiny handles costs handles × vertices
 * (minutes on a million vertices). */
#define BG_SCENE_MAX_HANDLES 1024

typedef enum bg_method {
    BG_METHOD_NEWTON = 0,         /* static */
    BG_METHOD_LOCAL_GLOBAL = 1,   /* static */
    BG_METHOD_VARIATIONAL = 2,    /* dynamic: the variational implicit midpoint rule */
    BG_METHOD_BACKWARD_EULER = 3, /* dynamic: the dissipative baseline */
    BG_METHOD_QUASI_NEWTON = 4,   /* static: L-BFGS on local/global's prefactored Laplacian */
} bg_method;

#define BG_METHOD_COUNT 5

/* Whether a method integrates in time (variational, backward-euler). */
int bg_method_is_dynamic(bg_method method);

/* "newton", "local-global", "variational", "backward-euler", "quasi-newton". */
const char *bg_method_name(bg_method method);
/* Parses a method name; BG_ERR_INVALID naming the accepted names otherwise. */
bg_status bg_method_parse(const char *name, bg_method *out, bg_error_t *err);

typedef enum bg_task_kind {
    BG_TASK_STATIC = 0,
    BG_TASK_DYNAMIC = 1,
    BG_TASK_MORPH = 2,
    BG_TASK_PARAMETERIZE = 3,
    BG_TASK_SURFACE_EDIT = 4, /* spokes-and-rims ARAP on a triangle surface */
} bg_task_kind;

/* task {"kind": "dynamic", "dt", "steps", "output_every", "damping", "energy_limit"}. */
typedef struct bg_dynamic_task {
    double dt;          /* time step h (s) */
    int steps;          /* number of steps */
    int output_every;   /* a frame every this many steps (default: steps/100, at least 1) */
    double damping;     /* momentum decays as exp(−damping·t), independent of h (1/s) */
    int energy_limit;   /* variational: a step that would create energy is redone dissipatively
                           (bg_dynamics.h); default true */
} bg_dynamic_task_t;

/* Lamé parameters of ψ = mu |F − R|² + (lambda/2)(tr Y − n)², and the mass
 * density (needed only for gravity). */
typedef struct bg_material {
    double mu;
    double lambda;
    double density;
} bg_material_t;

typedef enum bg_reference_kind {
    BG_REFERENCE_NONE = 0,
    BG_REFERENCE_POSITIONS, /* given in the scene: reference[] filled */
    BG_REFERENCE_NEWTON,    /* a tight Newton solve computes it at run time */
} bg_reference_kind;

/* How a handle moves its vertices, kept so that the initial guess can
 * interpolate the motion into the body (bg_initial). */
typedef enum bg_motion_kind {
    BG_MOTION_FIXED = 0,     /* held at rest */
    BG_MOTION_RIGID = 1,     /* p ↦ R(axis, angle)(p − center) + center + translate */
    BG_MOTION_POSITIONS = 2, /* given positions: mean_displacement summarises them */
} bg_motion_kind;

typedef struct bg_scene_motion {
    bg_motion_kind kind;
    int32_t count;          /* selected vertices */
    int32_t *vertices;      /* count indices, increasing; owned */
    double axis[3];         /* unit axis (planar: (0, 0, 1)) */
    double radians;         /* rotation angle, right-handed about axis */
    double center[3];
    double translate[3];
    double mean_displacement[3];
    double duration;        /* > 0: the motion is reached progressively over this time
                               (dynamic scenes); 0: in place from the start */
} bg_scene_motion_t;

typedef enum bg_initial_kind {
    BG_INITIAL_REST = 0,
    BG_INITIAL_GIVEN = 1,       /* scale, positions or random: initial[] as parsed */
    BG_INITIAL_INTERPOLATE = 2, /* the handles' motions interpolated into the body */
} bg_initial_kind;

/* Set-up work done while loading a scene (the starting guess), which every
 * run of it reports in its set-up list and wall time. */
typedef struct bg_scene_prep {
    const char *name;        /* static text */
    int64_t factorizations;  /* numeric factorizations it did */
    double seconds;
} bg_scene_prep_t;
#define BG_SCENE_MAX_PREP 3

typedef struct bg_scene {
    char *path;        /* the scene file as given ("<memory>" when parsed from text) */
    char *name;        /* the "name" field, else the file's stem */
    char *mesh_source; /* resolved mesh path, or "generated box 40x8x8" */
    bg_mesh_format mesh_format; /* format of a file mesh; MEDIT for generated volume
                                   meshes, OBJ for generated planar ones */
    bg_mesh_t *mesh;            /* validated rest mesh */
    int32_t reoriented;         /* elements the validator reoriented */
    bg_material_t material;
    double gravity[3];          /* acceleration (m/s²); all zero when absent */
    uint8_t *constrained;       /* nv*dim: 1 where the coordinate is prescribed */
    double *target;             /* nv*dim: prescribed value where constrained, rest value elsewhere */
    double *initial;            /* nv*dim: start positions; constrained coordinates = target */
    bg_reference_kind reference_kind;
    double *reference;          /* nv*dim when reference_kind == POSITIONS, else NULL */
    int32_t handle_count;       /* handles in the scene */
    bg_scene_motion_t *motions; /* handle_count motions; owned */
    bg_initial_kind initial_kind;
    int32_t constrained_vertices; /* vertices with at least one constrained coordinate */
    bg_task_kind task;
    bg_dynamic_task_t dynamic;  /* when task == BG_TASK_DYNAMIC */
    double *velocity;           /* nv*dim initial velocities ("velocity"), or NULL (at rest) */
    double *morph_target;       /* morph: nv*dim target positions (same connectivity) */
    int morph_frames;           /* morph: frames from t = 0 to t = 1, at least 2 */
    /* parameterize: `mesh` is the planar UV mesh (same connectivity, x = the
     * Tutte start), `surface` the 3D input, `rest_edges` each triangle's
     * isometric 2D rest frame (ne·4, see bg_elastic_new_from_rest). */
    bg_mesh_t *surface;
    double *rest_edges;
    double alpha, beta;
    double barrier;             /* parameterize: area-barrier weight relative to μ (default 1,
                                   0: none; see bg_elastic_set_barrier) */
    int prepared;               /* bg_prepare_scene has run: the scene is ready to solve */
    bg_method method;           /* solver.method, default newton */
    bg_method inner;            /* solver.inner, dynamic scenes: what minimises each time
                                   step's energy, BG_METHOD_NEWTON (default) or
                                   BG_METHOD_QUASI_NEWTON (bg_dynamics.h) */
    double tolerance;           /* solver.tolerance on the relative gradient, default 1e-8 */
    int continuation_off;       /* solver.continuation false: Newton and quasi-newton solve a
                                   nearly incompressible scene in one solve
                                   (bg_static_continues) */
    int max_iterations;         /* solver.max_iterations (or its entry for `method`),
                                   default 200 */
    int method_max_iterations[BG_METHOD_COUNT]; /* solver.max_iterations given per method
                                                   ({"newton": n, ...}); 0 where not given */
    bg_scene_prep_t prep[BG_SCENE_MAX_PREP]; /* set-up done before solving (bg_initial,
                                                bg_param), by bg_prepare_scene */
    int prep_count;
} bg_scene_t;

#define BG_SCENE_DEFAULT_TOLERANCE 1e-8
#define BG_SCENE_DEFAULT_MAX_ITERATIONS 200

/* How a scene finds the files it names. Zero-initialised = defaults. */
typedef struct bg_scene_options {
    /* Folders (separated by ':') where a relative file that is not found
     * beside the scene is looked up by its file name, in order; NULL or ""
     * for none. Borrowed for the duration of the call. The `biotgrid`
     * command fills it from --mesh-path and BIOTGRID_MESH_PATH. */
    const char *search_path;
    /* Size caps on the mesh (0: the library's own BG_MESH_MAX_*). A
     * generated mesh over a cap is refused before anything is allocated; a
     * file mesh is bounded by BG_MESH_FILE_MAX_BYTES while it is read and
     * checked against the caps right after. A broker sets them per job. */
    int64_t max_vertices;
    int64_t max_elements;
    /* Cap on elements × steps (dynamic) or × frames (morph), 0: none;
     * checked, like the size caps, before a generated mesh is built. */
    double max_work;
    /* Non-zero: the scene may name only files inside its own folder — a
     * relative path without ".." components; an absolute path or one that
     * leaves the folder is BG_ERR_INVALID, and the search path is not used.
     * A broker parses submitted scenes so, never reading its own files. */
    int confined;
    /* The scene's name in messages instead of `path` (NULL: path). */
    const char *display_name;
} bg_scene_options_t;

/*
 * Parses and validates a scene from JSON text, running no solve (see
 * bg_prepare_scene). `path` names the scene in messages and
 * its directory is the base for relative paths inside it (NULL: "<memory>"
 * and the current directory); `options` may be NULL. A file the scene names
 * that exists nowhere gives BG_ERR_NOT_FOUND. Caller owns *out.
 */
bg_status bg_scene_parse_with(const char *json, size_t length, const char *path,
                              const bg_scene_options_t *options, bg_scene_t **out,
                              bg_error_t *err);

/* Reads, parses and validates a scene file (at most BG_SCENE_MAX_BYTES), running no
 * solve; `options` may be NULL. */
bg_status bg_scene_load_with(const char *path, const bg_scene_options_t *options,
                             bg_scene_t **out, bg_error_t *err);


/*
 * A fraction f of a rigid motion applied to point x (dim coordinates):
 * rotate by f·radians about the axis through the centre, translate by
 * f·translate (a screw motion: no collapse at half turns, unlike blending
 * positions). f = 1 is the handle's full motion.
 */
void bg_motion_screw(const bg_scene_motion_t *motion, int dim, double f, const double *x,
                     double *out);

/*
 * Prescribed values at time t (dynamic scenes: handles with a duration
 * move a fraction min(t/duration, 1) of their motion, screw-interpolated
 * for rigid motions). Writes nv*dim values; only constrained coordinates
 * are meaningful, the others hold rest positions.
 */
void bg_scene_targets_at(const bg_scene_t *scene, double t, double *out);

/* The iteration cap of `method`: its entry in solver.max_iterations when the
 * scene gives one per method, else solver.max_iterations. */
int bg_scene_max_iterations(const bg_scene_t *scene, bg_method method);

/* Frees the scene and everything it owns; sets *scene to NULL; accepts NULL. */
void bg_scene_destroy(bg_scene_t **scene);

#endif
