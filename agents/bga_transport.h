/*
 * bga_transport — multipart messages over ZeroMQ sockets, for the agent
 * (ROUTER: a routing-id envelope frame, then the message) and the client
 * (DEALER: the message alone). The only module besides bga_agent and
 * bga_client that touches libzmq.
 */
#ifndef BGA_TRANSPORT_H
#define BGA_TRANSPORT_H

#include <zmq.h>

#include "bg_error.h"
#include "bga_wire.h"

/* A received message: up to BGA_WIRE_MAX_FRAMES + 1 frames are kept (one
 * more than any schema has, so an oversized count still decodes to a
 * frame-count error), the total part count is recorded. */
typedef struct bga_received {
    int envelope; /* routing-id frames kept apart (0 or 1) */
    zmq_msg_t route;
    int count; /* frames kept in part[] */
    int total; /* parts received after the envelope */
    zmq_msg_t part[BGA_WIRE_MAX_FRAMES + 1];
    size_t bytes; /* all parts */
} bga_received_t;

/*
 * Receives one whole multipart message (blocking; retries on EINTR only
 * after its first part). `envelope` = 1 on a ROUTER. BG_ERR_IO with
 * errno's text on failure, BG_ERR_UNSUPPORTED ("interrupted") when a
 * signal arrived before any part. On success the caller closes *r with
 * bga_received_close.
 */
bg_status bga_recv(void *socket, int envelope, bga_received_t *r, bg_error_t *err);
void bga_received_close(bga_received_t *r);
/* Views of the kept frames (count of them). */
void bga_received_view(const bga_received_t *r, bga_frame_t *views);

/* Sends frames as one multipart message, preceded by `route` when non-NULL. */
bg_status bga_send(void *socket, const zmq_msg_t *route, const bga_frames_t *frames,
                   bg_error_t *err);
/* Sends raw frames (tests send malformed messages with it). */
bg_status bga_send_views(void *socket, const bga_frame_t *frames, int nframes, bg_error_t *err);

#endif
