# mk/links.mk — the link lab: a stream that fits every link (PROTOCOL.md §7.2
# `link`, server/net/ladder.c). Two network namespaces joined by a userspace
# shaper (bench/links/shaper.c: rate, delay, loss, drop-tail queue; this
# kernel has no netem), oceand in one, viewers in the other. Needs root; a
# run without it says so (bench) or runs the loopback part only (test).
#
#   make bench-links    one JSON object per link and role: fps, share of ticks,
#                       latency p50/p95, kB/frame, codec shares, rung, set round
#                       trip; each link with `--role all`, then through an edge
#                       (`--role edge` fed by `--role sim` over nats-server;
#                       rows NAME-edge) (LINKS="10M:10000:50:0 10M-edge:10000:50:0:edge"
#                       to choose; see bench/links/run.sh)
#   make bench-links-load   the encode cost of 200 viewers spread over the five
#                       links (40 each, a link per viewer: the shaper's per-flow
#                       mode) against the same 200 on loopback, in the same run:
#                       one JSON object per row and run, medians, ratios
#                       (bench/links/many.py; BENCH_LINKS_LOAD_ARGS="--runs 5")
#   make test-links     behaviour, never timings: the ladder steps down on a slow
#                       link (and through an edge), a stall recovers to temporal
#                       tiles that decode, replies overtake frames, adapt:false
#                       pins (~1.5 min)

SHAPER := $(BUILD)/shaper
LINKS ?=

TESTS   += test-links
BENCHES += bench-links bench-links-load
BENCH_LINKS_LOAD_ARGS ?=

$(SHAPER): bench/links/shaper.c
	@mkdir -p $(dir $@)
	$(CC) -O2 -g -std=c11 $(WARN) -o $@ $<

.PHONY: bench-links bench-links-load test-links screenshot-link
# The web page through the 2 Mbit/s, 150 ms link, with its HUD (docs/gallery/link-2mbit.png).
screenshot-link: $(BUILD)/oceand $(SHAPER) $(BUILD)/web/index.html
	PAGE_SHOT=docs/gallery/link-2mbit.png WEB_ROOT=$(BUILD)/web bench/links/run.sh $(BUILD)/oceand $(SHAPER) 2M:2000:150:0
bench-links: $(BUILD)/oceand $(SHAPER)
	bench/links/run.sh $(BUILD)/oceand $(SHAPER) $(LINKS)

bench-links-load: $(BUILD)/oceand $(SHAPER) $(BUILD)/load_client
	/usr/bin/python3 bench/links/many.py --oceand $(BUILD)/oceand --shaper $(SHAPER) --load-client $(BUILD)/load_client $(BENCH_LINKS_LOAD_ARGS)

test-links: $(BUILD)/oceand $(SHAPER) $(BUILD)/frame_check
	/usr/bin/python3 tests/links/test_links.py --oceand $(BUILD)/oceand --shaper $(SHAPER) --frame-check $(BUILD)/frame_check
