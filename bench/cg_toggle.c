/* Callgrind collection switch for bench_replay.py --callgrind: build with
 *   cc -shared -fPIC -O1 -o /tmp/cg_toggle.so bench/cg_toggle.c
 * and run the replay under valgrind --tool=callgrind --collect-atstart=no. */
#include <valgrind/callgrind.h>

void cg_toggle(void) { CALLGRIND_TOGGLE_COLLECT; }
