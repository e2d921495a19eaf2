/* cmd_broker — `biotgrid broker`: runs the broker daemon (bgb_broker). */
#ifndef CMD_BROKER_H
#define CMD_BROKER_H

/* The --help text, also `biotgrid help broker` and the manual page. */
extern const char bg_cmd_broker_usage[];

/* argv[0] is "broker". Returns 0 after SIGTERM/SIGINT, 1 when the daemon
 * cannot start, 2 on bad options or a bad config. */
int bg_cmd_broker(int argc, char **argv);

#endif
