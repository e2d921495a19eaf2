#include "bgb_goods.h"

#include <string.h>

static const char *const mech_names[BGB_MECHANISMS] = {"central", "catallactic", "posted"};
static const char *const good_names[BGB_GOODS] = {"rotation-fit", "sparse-solve",
                                                  "integration-step", "cores", "memory"};

const char *bgb_mechanism_name(bgb_mechanism m)
{
    return (int)m >= 0 && (int)m < BGB_MECHANISMS ? mech_names[m] : "unknown";
}

int bgb_mechanism_parse(const char *name)
{
    for (int i = 0; i < BGB_MECHANISMS; i++)
        if (name && strcmp(name, mech_names[i]) == 0)
            return i;
    return -1;
}

const char *bgb_good_name(int good)
{
    return good >= 0 && good < BGB_GOODS ? good_names[good] : "unknown";
}
