# mk/hostile.mk — hostile-client battery and churn test (docs/reliability.md) against a real
# oceand on 127.0.0.1: malformed / nested / huge / compressed / binary messages,
# set floods, connection storms, stalled, half-open and vanishing clients,
# 1000 connect/subscribe/disconnect cycles, foreign Host headers (DNS
# rebinding), bad handshakes, unread replies, descriptor exhaustion (ulimit -n),
# unmasked frames, web-root symlinks, ping floods, illegal control frames,
# subscription churn, pipelined HTTP, resolution flapping, log floods on a slow
# stderr pipe, params fan-out from many controllers, state-file symlink,
# ulimit -f, SIGUSR1/2, over-long paths, fragment floods, query/probe abuse,
# layer floods (every field x LOD x bound at N = 512 against the encode
# budget) and the control budget (50 clients of max-size subscribes, a
# controller's sets).
# Budget: < 5 min on 2 cores (54 cases and the cluster's 5). Each case has its own daemon and
# observer, and most of the battery's wall time is observer windows (a daemon
# at N = 64 uses ~0.1 core): the light cases run HOSTILE_JOBS (3) processes at
# once, then the ones that load the daemon (N > 64, floods of clients or sets;
# SOLO in the script) one at a time alone.
#
#   make test-hostile     the battery; "N passed, M failed", non-zero on a failure
#   make bench-hostile    the same run, one case at a time, figures as one JSON line per case on stdout
# HOSTILE_ARGS passes options, e.g. HOSTILE_ARGS="-k churn,set_flood" or "--strict";
# HOSTILE_JOBS=1 runs the cases one after another.
#   make bench-control-budget [BEFORE=old/oceand]   the control_budget attack, before/after alternating

HOSTILE_ARGS ?=
HOSTILE_JOBS ?= 3

TESTS += test-hostile
BENCHES += bench-hostile bench-control-budget

.PHONY: test-hostile bench-hostile bench-control-budget
# The cluster's hostile cases (a rogue publisher on the NATS prefix) run after
# the battery, with a nats-server, a sim and an edge of their own.
test-hostile: $(BUILD)/oceand
	/usr/bin/python3 tests/hostile/test_hostile.py --oceand $(BUILD)/oceand --jobs $(HOSTILE_JOBS) $(HOSTILE_ARGS)
	/usr/bin/python3 tests/cluster/test_cluster_hostile.py --oceand $(BUILD)/oceand

bench-hostile: $(BUILD)/oceand
	@/usr/bin/python3 tests/hostile/test_hostile.py --oceand $(BUILD)/oceand --bench $(HOSTILE_ARGS)

bench-control-budget: $(BUILD)/oceand
	@/usr/bin/python3 bench/control_budget.py --oceand $(BUILD)/oceand $(if $(BEFORE),--before $(BEFORE))
