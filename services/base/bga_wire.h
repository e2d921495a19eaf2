/*
 * bga_wire — the biotgrid wire protocol: pure encoders and decoders over
 * ZeroMQ-style multipart messages, with no sockets.
 *
 * A message is a list of frames:
 *   frame 0  header, BGA_WIRE_HEADER_BYTES, little-endian:
 *              magic "bgwp" (4 bytes), version u16, type u16,
 *              job u64, seq u64, sender u64, receiver u64, flags u32, reserved u32
 *   frame 1  the type's scalar fields, 8 bytes each (i64 or f64, LE), in
 *            schema order; exactly nfields*8 bytes
 *   frame 2… one frame per array of the type's schema, in order: f64 (LE),
 *            i32 (LE) or bytes (UTF-8 text); an optional array may be empty
 * A binary header rather than JSON: fixed size, no parser, every field
 * checked by position. sender/receiver name role or agent ids for the
 * market roles (0 when a socket identifies the peer); flags and reserved
 * must be zero.
 *
 * Each message type has a schema (static table in bga_wire.c): fields with
 * a kind and an allowed range, arrays with an element kind, a length rule
 * (a product of fields and a constant, or free), a finiteness rule and an
 * index range (lower bound, upper bound taken from a field). Decoding
 * checks all of it plus a per-type consistency check, and fails with a
 * bga_wire_error_t naming the frame and field. Types 0x0001–0x00ff are
 * control, 0x01xx rotation-fit, 0x02xx sparse-solve, 0x03xx integration
 * step; 0x10xx market roles (0x1001–0x1019, bgm_codec); 0x11xx the live
 * market between the broker and the agents (0x1101–0x1111, bga_mmsg).
 *
 * Ownership: a decoded bga_msg_t only points into the caller's frames
 * (valid while they are); nothing is allocated. bga_wire_encode fills a
 * bga_frames_t that owns its buffers (bga_frames_free).
 */
#ifndef BGA_WIRE_H
#define BGA_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

/* 2: solve-setup carries its options (a field added to a type's layout,
 * so a peer of version 1 would misread it; added types alone keep the
 * version). The options field was prefer_solves, 0 or 1, in the first
 * version 2 peers; the bit BGA_SOLVE_ORDERED widened its range, which an
 * older version 2 agent refuses (out of range) rather than misreads, so
 * the version stayed. */
#define BGA_WIRE_VERSION 2
#define BGA_WIRE_HEADER_BYTES 48
#define BGA_WIRE_MAX_FIELDS 20
#define BGA_WIRE_MAX_ARRAYS 8
#define BGA_WIRE_MAX_FRAMES (2 + BGA_WIRE_MAX_ARRAYS)
/* Default caps: one frame, and the whole message. The 201,600-tet box's
 * per-element Hessian blocks are 126 MB; a partition sends less. */
#define BGA_WIRE_MAX_FRAME_BYTES ((size_t)256 << 20)
#define BGA_WIRE_MAX_MESSAGE_BYTES ((size_t)1 << 30)
#define BGA_WIRE_MAX_TEXT 4096
/* Mesh sizes a message may describe: the engine's caps (BG_MESH_MAX_VERTICES,
 * BG_MESH_MAX_ELEMENTS in bg_mesh.h; a test checks they agree), repeated
 * here so the codec needs no engine header. */
#define BGA_WIRE_MAX_VERTICES 50000000
#define BGA_WIRE_MAX_ELEMENTS 200000000

typedef enum bga_type {
    BGA_HEARTBEAT = 0x0001,      /* ping, and the agent's status as the pong */
    BGA_ERROR = 0x0002,          /* error reply: what was wrong, where */
    BGA_RELEASE = 0x0003,        /* free the job's state on the agent */
    BGA_ACK = 0x0004,            /* success reply without data */
    BGA_ROTFIT_SETUP = 0x0101,   /* a partition: elements, rest data, map, material */
    BGA_ROTFIT_CALL = 0x0102,    /* positions in */
    BGA_ROTFIT_RESULT = 0x0103,  /* energy, gradient, Hessian values out */
    BGA_SURF_SETUP = 0x0104,     /* a surface's vertex partition for the spokes-and-rims fit */
    BGA_SOLVE_SETUP = 0x0201,    /* lower-triangle CSC pattern */
    BGA_SOLVE_FACTOR = 0x0202,   /* values (+ shift) → factor */
    BGA_SOLVE_FACTORED = 0x0203, /* factorization outcome */
    BGA_SOLVE_RHS = 0x0204,      /* right-hand sides → solve */
    BGA_SOLVE_RESULT = 0x0205,   /* solutions */
    BGA_INTEG_SETUP = 0x0301,    /* masses, q, velocities, targets, constraints, h, damping */
    BGA_INTEG_PREDICT = 0x0302,  /* a step's (or a redo's) end targets → its inertia data */
    BGA_INTEG_INERTIA = 0x0303,  /* prediction y, coefficient, solve targets, candidate starts */
    BGA_INTEG_UPDATE = 0x0304,   /* q* and ∇W(q*) in → the trial end state */
    BGA_INTEG_STATE = 0x0305,    /* the committed state: q, kinetic energy, momenta */
    BGA_INTEG_TRIAL = 0x0306,    /* a trial end state: q_next, kinetic energy, handle work */
    BGA_INTEG_ACCEPT = 0x0307,   /* commit the trial (answered with INTEG_STATE) */
} bga_type;

/* What went wrong, carried by BGA_ERROR replies (stable numbers). */
typedef enum bga_wire_code {
    BGA_WIRE_OK = 0,
    BGA_WIRE_TRUNCATED = 1, /* a frame shorter than its content */
    BGA_WIRE_OVERSIZE = 2,  /* a frame or the message over its cap */
    BGA_WIRE_BAD_MAGIC = 3,
    BGA_WIRE_WRONG_VERSION = 4,
    BGA_WIRE_UNKNOWN_TYPE = 5,
    BGA_WIRE_FRAME_COUNT = 6,
    BGA_WIRE_BAD_LENGTH = 7,    /* an array's length breaks its rule */
    BGA_WIRE_NOT_FINITE = 8,    /* NaN/Inf where a finite value is required */
    BGA_WIRE_OUT_OF_RANGE = 9,  /* a field or index outside its range */
    BGA_WIRE_INCONSISTENT = 10, /* fields or arrays disagree (pattern order, ...) */
    BGA_WIRE_BAD_HEADER = 11,   /* non-zero flags/reserved */
    BGA_WIRE_NO_JOB = 20,       /* the agent holds no state for this job */
    BGA_WIRE_BUSY = 21,         /* no free slot */
    BGA_WIRE_WRONG_STATE = 22,  /* e.g. solve before factor, wrong service */
    BGA_WIRE_NUMERIC = 23,      /* the computation failed (not positive definite) */
    BGA_WIRE_INTERNAL = 24,     /* out of memory or another agent-side failure */
    BGA_WIRE_UNEXPECTED = 25,   /* a valid message the receiver does not serve */
} bga_wire_code;

typedef struct bga_wire_error {
    bga_wire_code code;
    int frame;      /* frame index, −1 when not about one frame */
    char field[48]; /* schema name of the field or array, or "" */
    char message[BG_ERROR_MESSAGE_MAX];
} bga_wire_error_t;

typedef struct bga_header {
    uint16_t version;
    uint16_t type;
    uint64_t job;
    uint64_t seq;
    uint64_t sender;
    uint64_t receiver;
} bga_header_t;

typedef enum bga_elem {
    BGA_ELEM_F64 = 1,
    BGA_ELEM_I32 = 2,
    BGA_ELEM_BYTES = 3,
} bga_elem;

/* One array of a message. For encoding, data points to count host values
 * (double, int32_t or char); after decoding, to count wire values in the
 * caller's frame (little-endian, possibly unaligned: read them with the
 * bga_msg_* accessors). */
typedef struct bga_array {
    const void *data;
    size_t count;
} bga_array_t;

typedef struct bga_msg {
    bga_header_t header;
    int nfields, narrays; /* set by decode; encode takes them from the schema */
    union {
        int64_t i;
        double f;
    } field[BGA_WIRE_MAX_FIELDS];
    bga_array_t array[BGA_WIRE_MAX_ARRAYS];
} bga_msg_t;

typedef struct bga_frame {
    const uint8_t *data;
    size_t size;
} bga_frame_t;

typedef struct bga_frames {
    int count;
    uint8_t *data[BGA_WIRE_MAX_FRAMES];
    size_t size[BGA_WIRE_MAX_FRAMES];
} bga_frames_t;

typedef struct bga_limits {
    size_t max_frame_bytes;
    size_t max_message_bytes;
} bga_limits_t;

/* The default caps above. */
bga_limits_t bga_wire_default_limits(void);

/*
 * Field and array positions of every type (the schema order). Encoders
 * fill msg.field[...] / msg.array[...] at these positions.
 */
enum { /* HEARTBEAT */
       BGA_HB_SLOTS,
       BGA_HB_FREE,
       BGA_HB_SERVICES,
       BGA_HB_JOBS,
       BGA_HB_NFIELDS
};
enum { /* HEARTBEAT arrays */ BGA_HB_NAME, BGA_HB_NARRAYS };
enum { /* ERROR */
       BGA_ERR_CODE,
       BGA_ERR_FRAME,
       BGA_ERR_TYPE,
       BGA_ERR_SEQ,
       BGA_ERR_NFIELDS
};
enum { /* ERROR arrays */ BGA_ERR_FIELD, BGA_ERR_MESSAGE, BGA_ERR_NARRAYS };
enum { /* ACK */ BGA_ACK_TYPE, BGA_ACK_NFIELDS };
enum { /* ROTFIT_SETUP */
       BGA_RS_DIM,
       BGA_RS_NODES,
       BGA_RS_NV,
       BGA_RS_NE,
       BGA_RS_NGLOBAL,
       BGA_RS_MU,
       BGA_RS_LAMBDA,
       BGA_RS_BARRIER,
       BGA_RS_BLOCK,
       BGA_RS_NVAL,
       BGA_RS_LEASE_MS,
       BGA_RS_NFIELDS
};
enum { /* ROTFIT_SETUP arrays */
       BGA_RS_ELEMENTS,
       BGA_RS_LOCAL_TO_GLOBAL,
       BGA_RS_REST_POSITIONS,
       BGA_RS_REST_EDGES,
       BGA_RS_SCATTER,
       BGA_RS_NARRAYS
};
enum { /* SURF_SETUP */ BGA_SU_NV,
       BGA_SU_NE,
       BGA_SU_NGLOBAL,
       BGA_SU_NOWNED,
       BGA_SU_LEASE_MS,
       BGA_SU_NFIELDS };
enum { /* SURF_SETUP arrays */ BGA_SU_TRIANGLES,
       BGA_SU_LOCAL_TO_GLOBAL,
       BGA_SU_REST_POSITIONS,
       BGA_SU_OWNED,
       BGA_SU_NARRAYS };
enum { /* ROTFIT_CALL */ BGA_RC_WANT, BGA_RC_NFIELDS };
enum { /* ROTFIT_CALL arrays */ BGA_RC_POSITIONS, BGA_RC_NARRAYS };
enum { /* ROTFIT_RESULT */
       BGA_RR_ENERGY,
       BGA_RR_FITS,
       BGA_RR_WARM,
       BGA_RR_POLAR,
       BGA_RR_SVD,
       BGA_RR_SECONDS,
       BGA_RR_NFIELDS
};
enum { /* ROTFIT_RESULT arrays */ BGA_RR_GRADIENT, BGA_RR_HESSIAN, BGA_RR_NARRAYS };
enum { /* SOLVE_SETUP */ BGA_SS_N, BGA_SS_NNZ, BGA_SS_LEASE_MS, BGA_SS_OPTIONS, BGA_SS_NFIELDS };
enum { /* SOLVE_SETUP arrays */ BGA_SS_COLPTR, BGA_SS_ROWIDX, BGA_SS_NARRAYS };
/* solve-setup's options (bits): the system will be solved far more often
 * than factored (bg_sparse_prefer_solves); the pattern is already in its
 * factor's order (bg_sparse_reorder's, done by the sender: the agent
 * keeps it, bg_sparse_keep_order). */
enum { BGA_SOLVE_PREFER_SOLVES = 1, BGA_SOLVE_ORDERED = 2 };
enum { /* SOLVE_FACTOR */ BGA_SF_SHIFT, BGA_SF_NFIELDS };
enum { /* SOLVE_FACTOR arrays */ BGA_SF_VALUES, BGA_SF_NARRAYS };
enum { /* SOLVE_FACTORED */
       BGA_SD_POSDEF,
       BGA_SD_ANALYZE_SECONDS,
       BGA_SD_FACTOR_SECONDS,
       BGA_SD_FLOPS,
       BGA_SD_FACTOR_NONZEROS,
       BGA_SD_NFIELDS
};
enum { /* SOLVE_FACTORED arrays */ BGA_SD_MESSAGE, BGA_SD_NARRAYS };
enum { /* SOLVE_RHS */ BGA_SR_NRHS, BGA_SR_NFIELDS };
enum { /* SOLVE_RHS arrays */ BGA_SR_RHS, BGA_SR_NARRAYS };
enum { /* SOLVE_RESULT */ BGA_SX_SECONDS, BGA_SX_NFIELDS };
enum { /* SOLVE_RESULT arrays */ BGA_SX_X, BGA_SX_NARRAYS };
enum { /* INTEG_SETUP */ BGA_IS_DIM,
       BGA_IS_NV,
       BGA_IS_H,
       BGA_IS_DAMPING,
       BGA_IS_LEASE_MS,
       BGA_IS_NFIELDS };
enum { /* INTEG_SETUP arrays */ BGA_IS_MASS,
       BGA_IS_Q,
       BGA_IS_VELOCITY,
       BGA_IS_T0,
       BGA_IS_CONSTRAINED,
       BGA_IS_GRAVITY,
       BGA_IS_NARRAYS };
enum { /* INTEG_PREDICT */ BGA_IP_VARIATIONAL, BGA_IP_TRIAL, BGA_IP_PREDICTOR, BGA_IP_NFIELDS };
enum { /* INTEG_PREDICT arrays */ BGA_IP_T1, BGA_IP_NARRAYS };
enum { /* INTEG_INERTIA */ BGA_II_COEF,
       BGA_II_STATE_SCALE,
       BGA_II_NCAND,
       BGA_II_SECONDS,
       BGA_II_NFIELDS };
enum { /* INTEG_INERTIA arrays */ BGA_II_PREDICT,
       BGA_II_TARGETS,
       BGA_II_CANDIDATES,
       BGA_II_NARRAYS };
enum { /* INTEG_UPDATE arrays */ BGA_IU_QSTAR, BGA_IU_GRAD, BGA_IU_NARRAYS };
enum { /* INTEG_STATE */ BGA_IT_KINETIC,
       BGA_IT_LINEAR_X,
       BGA_IT_LINEAR_Y,
       BGA_IT_LINEAR_Z,
       BGA_IT_ANGULAR_X,
       BGA_IT_ANGULAR_Y,
       BGA_IT_ANGULAR_Z,
       BGA_IT_STEPS,
       BGA_IT_SECONDS,
       BGA_IT_NFIELDS };
enum { /* INTEG_STATE arrays */ BGA_IT_Q, BGA_IT_NARRAYS };
enum { /* INTEG_TRIAL */ BGA_IR_KINETIC, BGA_IR_WORK, BGA_IR_SECONDS, BGA_IR_NFIELDS };
enum { /* INTEG_TRIAL arrays */ BGA_IR_QNEXT, BGA_IR_NARRAYS };

/* Market role messages, types 0x1001..0x1019 (see market/bgm_codec.h for
 * their meaning): all share one schema. */
#define BGA_MARKET_FIRST 0x1001
#define BGA_MARKET_LAST 0x1019
#define BGA_MARKET_CANDIDATES 8
#define BGA_MARKET_MAX_AGENT ((1 << 24) - 1)
enum { /* market */
       BGA_MK_GOOD,
       BGA_MK_HOPS,
       BGA_MK_NCAND,
       BGA_MK_REQ,
       BGA_MK_ATTEMPT,
       BGA_MK_ORIGIN,
       BGA_MK_PRICE,
       BGA_MK_A,
       BGA_MK_B,
       BGA_MK_C,
       BGA_MK_NFIELDS
};
enum { /* market arrays */ BGA_MK_CAND, BGA_MK_CAND_PRICE, BGA_MK_CAND_SPEED, BGA_MK_NARRAYS };

/* The live market's messages between the broker and the agents, types
 * 0x1101..0x1111 (agents/bga_mmsg.h gives their meaning; the low byte is
 * the bga_mmsg type): all share one schema. The job is the header's job;
 * sender and receiver are 0 (the socket names the peer). Each field and
 * array is present in every type, zero where the type does not use it. */
#define BGA_LIVE_FIRST 0x1101
#define BGA_LIVE_LAST 0x1111
#define BGA_LIVE_GOODS 5
enum { /* live market */
       BGA_LM_AGENT,
       BGA_LM_TARGET,
       BGA_LM_ORIGIN,
       BGA_LM_SERVICES,
       BGA_LM_RESOURCE,
       BGA_LM_SLOTS,
       BGA_LM_FREE_SLOTS,
       BGA_LM_GOOD,
       BGA_LM_HOPS,
       BGA_LM_ATTEMPT,
       BGA_LM_MARGIN,
       BGA_LM_LOAD_SLOPE,
       BGA_LM_TERM,
       BGA_LM_QUANTITY,
       BGA_LM_PRICE,
       BGA_LM_PARENT,
       BGA_LM_SERVES,
       BGA_LM_NFIELDS
};
enum { /* live market arrays: capacity = cores, memory, free cores, free memory */
       BGA_LM_FLOOR,
       BGA_LM_PRICES,
       BGA_LM_CAPACITY,
       BGA_LM_NEIGHBOURS,
       BGA_LM_NAME,
       BGA_LM_ENDPOINT,
       BGA_LM_REASON,
       BGA_LM_NARRAYS
};

/* ROTFIT_CALL want bits. */
#define BGA_WANT_GRADIENT 1
#define BGA_WANT_HESSIAN 2
#define BGA_WANT_PROJECTED 4 /* with HESSIAN: the PSD-projected Hessian */

/* Service bits (HEARTBEAT services field, --services). */
#define BGA_SERVICE_ROTFIT 1
#define BGA_SERVICE_SOLVE 2
#define BGA_SERVICE_INTEG 4

/* "heartbeat", "rotfit-setup", ...; "unknown" for types outside the table. */
const char *bga_type_name(uint16_t type);
/* Whether type is in the table. */
int bga_type_known(uint16_t type);
/* "truncated", "oversize", ... */
const char *bga_wire_code_name(bga_wire_code code);

/* Schema of a known type: number of fields and arrays, and their names. */
int bga_type_nfields(uint16_t type);
int bga_type_narrays(uint16_t type);

/*
 * Decodes and validates frames[0..nframes) into *msg (views into the
 * frames). Returns BGA_WIRE_OK or the first problem found, described in
 * *werr; msg->header is filled whenever the header frame itself decoded,
 * so an error reply can quote the job and sequence number.
 */
bga_wire_code bga_wire_decode(const bga_frame_t *frames, int nframes, const bga_limits_t *limits,
                              bga_msg_t *msg, bga_wire_error_t *werr);

/*
 * Encodes msg (header.type selects the schema; the version is written as
 * BGA_WIRE_VERSION) into *out, which the caller frees with bga_frames_free.
 * The message is validated by the same rules as decoding first, so an
 * agent never emits what a peer would reject; BG_ERR_INVALID then, with
 * the problem in err. BG_ERR_NOMEM when a buffer cannot be allocated.
 */
bg_status bga_wire_encode(const bga_msg_t *msg, bga_frames_t *out, bg_error_t *err);
void bga_frames_free(bga_frames_t *frames);

/* Views of an encoded message's frames (for decoding it again). */
void bga_frames_view(const bga_frames_t *frames, bga_frame_t *views);
/* Total bytes of an encoded message. */
size_t bga_frames_bytes(const bga_frames_t *frames);

/* A fresh message of the given type with every field and array zero. */
void bga_msg_init(bga_msg_t *msg, uint16_t type, uint64_t job, uint64_t seq);

/* Reads element i of a decoded array. */
double bga_msg_f64(const bga_msg_t *msg, int array, size_t i);
int32_t bga_msg_i32(const bga_msg_t *msg, int array, size_t i);
/* Copies a decoded array into host memory (count values of its kind). */
void bga_msg_copy_f64(const bga_msg_t *msg, int array, double *dst);
void bga_msg_copy_i32(const bga_msg_t *msg, int array, int32_t *dst);

/*
 * An ERROR reply to the message whose header is `to` (NULL: unknown),
 * carrying werr. Sets *out; encoding cannot fail for a valid werr except
 * for memory (BG_ERR_NOMEM).
 */
bg_status bga_wire_error_reply(const bga_header_t *to, const bga_wire_error_t *werr,
                               bga_frames_t *out, bg_error_t *err);

/* Fills werr (printf-style message); returns code. */
bga_wire_code bga_wire_fail(bga_wire_error_t *werr, bga_wire_code code, int frame,
                            const char *field, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));

#endif
