#include "bga_transport.h"

#include <errno.h>
#include <string.h>

void bga_received_close(bga_received_t *r)
{
    if (r->envelope)
        zmq_msg_close(&r->route);
    for (int i = 0; i < r->count; i++)
        zmq_msg_close(&r->part[i]);
    r->count = 0;
    r->envelope = 0;
}

static int more_parts(zmq_msg_t *m)
{
    return zmq_msg_more(m);
}

/* zmq_msg_recv retried on EINTR: once a message's first part is in, the
 * rest is already queued (ZeroMQ delivers multipart messages whole). */
static int recv_part(void *socket, zmq_msg_t *m)
{
    int rc;
    do
        rc = zmq_msg_recv(m, socket, 0);
    while (rc < 0 && errno == EINTR);
    return rc;
}

bg_status bga_recv(void *socket, int envelope, bga_received_t *r, bg_error_t *err)
{
    memset(r, 0, sizeof *r);
    zmq_msg_t first;
    zmq_msg_init(&first);
    if (zmq_msg_recv(&first, socket, 0) < 0) {
        const int e = errno;
        zmq_msg_close(&first);
        if (e == EINTR)
            return bg_error_set(err, BG_ERR_UNSUPPORTED, "interrupted");
        return bg_error_set(err, BG_ERR_IO, "receive failed: %s", zmq_strerror(e));
    }
    r->bytes = zmq_msg_size(&first);
    int more = more_parts(&first);
    if (envelope) {
        r->envelope = 1;
        r->route = first;
    } else {
        r->part[r->count++] = first;
        r->total = 1;
    }
    while (more) {
        zmq_msg_t tmp;
        zmq_msg_t *m = r->count < BGA_WIRE_MAX_FRAMES + 1 ? &r->part[r->count] : &tmp;
        zmq_msg_init(m);
        if (recv_part(socket, m) < 0) {
            const int e = errno;
            zmq_msg_close(m);
            bga_received_close(r);
            return bg_error_set(err, BG_ERR_IO, "receive failed mid-message: %s", zmq_strerror(e));
        }
        r->bytes += zmq_msg_size(m);
        r->total++;
        more = more_parts(m);
        if (m == &tmp)
            zmq_msg_close(&tmp); /* beyond any schema: counted, not kept */
        else
            r->count++;
    }
    return BG_OK;
}

void bga_received_view(const bga_received_t *r, bga_frame_t *views)
{
    for (int i = 0; i < r->count; i++) {
        zmq_msg_t *m = (zmq_msg_t *)&r->part[i]; /* zmq_msg_data takes a non-const pointer */
        views[i].data = zmq_msg_data(m);
        views[i].size = zmq_msg_size(m);
    }
}

static bg_status send_part(void *socket, const void *data, size_t size, int more, bg_error_t *err)
{
    int rc;
    do
        rc = zmq_send(socket, data, size, more ? ZMQ_SNDMORE : 0);
    while (rc < 0 && errno == EINTR);
    if (rc < 0 && errno == EAGAIN)
        return bg_error_set(err, BG_ERR_IO,
                            "send failed: no connection took the message before the send "
                            "timeout (the peer is not reachable, or refused the handshake)");
    if (rc < 0)
        return bg_error_set(err, BG_ERR_IO, "send failed: %s", zmq_strerror(errno));
    return BG_OK;
}

bg_status bga_send(void *socket, const zmq_msg_t *route, const bga_frames_t *frames,
                   bg_error_t *err)
{
    bg_status st;
    if (route) {
        zmq_msg_t *rm = (zmq_msg_t *)route;
        st = send_part(socket, zmq_msg_data(rm), zmq_msg_size(rm), frames->count > 0, err);
        if (st != BG_OK)
            return st;
    }
    for (int i = 0; i < frames->count; i++) {
        st = send_part(socket, frames->data[i], frames->size[i], i + 1 < frames->count, err);
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

bg_status bga_send_views(void *socket, const bga_frame_t *frames, int nframes, bg_error_t *err)
{
    for (int i = 0; i < nframes; i++) {
        bg_status st = send_part(socket, frames[i].data, frames[i].size, i + 1 < nframes, err);
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}
