/* cmd_agent — `biotgrid agent`: runs one agent daemon (bga_agent). */
#ifndef CMD_AGENT_H
#define CMD_AGENT_H

/* argv[0] is "agent". Returns the exit status: 0 after SIGTERM/SIGINT,
 * 1 when the loop fails, 2 on bad options or a bad config. */
int bg_cmd_agent(int argc, char **argv);

#endif
