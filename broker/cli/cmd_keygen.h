/* cmd_keygen — `biotgrid keygen PREFIX`: a CURVE key pair for a broker or
 * an agent, PREFIX.key (secret, mode 0600) and PREFIX.pub (bga_curve). */
#ifndef CMD_KEYGEN_H
#define CMD_KEYGEN_H

/* The --help text, also `biotgrid help keygen` and the manual page. */
extern const char bg_cmd_keygen_usage[];

/* argv[0] is "keygen". 0 with the public key printed; 2 on bad input (no
 * PREFIX, a missing folder, a key file already there); 1 when the files
 * cannot be written or libzmq has no CURVE. */
int bg_cmd_keygen(int argc, char **argv);

#endif
