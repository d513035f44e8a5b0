# mk/tools.mk — tools for remote programs and operators:
#   build/ocean-tap           command-line client (tools/)
#   build/gen-config-doc      prints the configuration reference from the params table
#   make install              PREFIX (default /usr/local) and DESTDIR honoured
#   make config-doc           rewrite the configuration reference (docs/configuration.md)
#   test-tap                  ocean-tap + the Python example against a real daemon
#   test-tap-bodies           floating bodies: ocean-tap --launch/--follow/--bodies, ship.py
#   test-ops                  docker/ <-> apt list, install, configuration reference
#   test-python               the Python package proto/python (pip install, cascades vs query)
#   test-blender              the Blender add-on tools/blender/ in Debian's Blender, headless
#   test-sea-readers          the readers of measured seas (ocean-tap sea, oceand.sea) on tests/sea/fixtures

PROTO_LIB  ?= $(BUILD)/liboc_proto.a
OCEAN_LIB  ?= $(BUILD)/libocean.a
# Install layout: $(PREFIX)/bin/{oceand,ocean-tap}, $(PREFIX)/share/oceand/web/
# (the built web client), $(PREFIX)/lib/systemd/system/oceand.service (paths
# in the unit rewritten for PREFIX). Staged installs: make install DESTDIR=/tmp/x
PREFIX     ?= /usr/local
BINDIR     = $(PREFIX)/bin
WEBDIR     = $(PREFIX)/share/oceand/web
UNITDIR    = $(PREFIX)/lib/systemd/system
WEB_BUILD  := $(BUILD)/web

# ocean-tap, split by verb (tools/tap.h says which file holds what).
TAP_OBJS := $(addprefix $(BUILD)/obj/tools/,tap_main.o tap_session.o tap_watch.o tap_query.o tap_bake.o tap_body.o tap_sea_send.o \
              tap_sea.o tap_write.o tap_exr.o tap_surface.o \
              sea_doc.o sea_ndbc.o sea_ww3.o sea_cdip.o sea_fetch.o)
# OpenEXR 3.1 (Debian libopenexr-dev) for --format exr: its C API
# (OpenEXRCore) and Imath's half floats; --as-needed drops its C++ libraries.
EXR_CFLAGS = $(shell pkg-config --cflags OpenEXR 2>/dev/null)
EXR_LIBS   = -Wl,--as-needed $(shell pkg-config --libs OpenEXR 2>/dev/null) -Wl,--no-as-needed
$(BUILD)/obj/tools/tap_exr.o $(BUILD)/obj/tests/tap/exr_read.o: PKG_CFLAGS += $(EXR_CFLAGS)

BINS  += $(BUILD)/ocean-tap $(BUILD)/gen-config-doc
TESTS += test-tap test-ops test-python test-blender

$(BUILD)/ocean-tap: $(TAP_OBJS) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $(TAP_OBJS) $(PROTO_LIB) $(PKG_LIBS) $(EXR_LIBS)

# Cost and accuracy of the summed surface (tools/tap_surface.c) on synthetic cascades.
BINS += $(BUILD)/bench-surface
BENCHES += bench-tap-surface
$(BUILD)/bench-surface: $(BUILD)/obj/tools/bench_surface.o $(BUILD)/obj/tools/tap_surface.o
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
.PHONY: bench-tap-surface
bench-tap-surface: $(BUILD)/bench-surface
	@$(BUILD)/bench-surface 256

# ocean-tap baking from the live stream: frames/s, CPU per frame, skipped ticks.
BENCHES += bench-tap-bake
.PHONY: bench-tap-bake
bench-tap-bake: $(BUILD)/oceand $(BUILD)/ocean-tap
	@tests/tap/bench_bake.sh $(BUILD) 240

# Test helper: reads an EXR back with the OpenEXR library (tests/tap/run.sh).
BINS += $(BUILD)/exr-read
$(BUILD)/exr-read: $(BUILD)/obj/tests/tap/exr_read.o
	$(CC) $(CFLAGS) -o $@ $^ $(EXR_LIBS)

$(BUILD)/gen-config-doc: $(BUILD)/obj/scripts/gen-config-doc.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

# ---- tests (budget: < 90 s together) -------------------------------------
.PHONY: test-tap test-ops test-python test-blender config-doc install uninstall
# budget: < 60 s (Blender starts in ~1 s; the daemon's start and the queries take the rest)
test-blender: $(BUILD)/oceand $(BUILD)/ocean-tap
	@tests/blender/run.sh $(BUILD)

test-python: $(BUILD)/oceand
	@tests/tap/package.sh $(BUILD)

test-tap: $(BUILD)/ocean-tap $(BUILD)/oceand $(BUILD)/exr-read
	@tests/tap/run.sh $(BUILD)

test-ops: $(BUILD)/gen-config-doc $(BUILD)/oceand $(BUILD)/ocean-tap $(WEB_BUILD)/index.html
	@tests/tap/ops.sh $(BUILD)

# budget: < 60 s (2 s, and 10-25 s more under valgrind; no daemon, a local HTTP server the test starts itself)
TESTS += test-sea-readers
.PHONY: test-sea-readers
test-sea-readers: $(BUILD)/ocean-tap
	@/usr/bin/python3 tests/sea/test_readers.py $(BUILD)

# budget: < 45 s (~25 s: a boat followed for 5 s, ship.py for 8 + 2 s and a Ctrl-C, a dozen requests)
TESTS += test-tap-bodies
.PHONY: test-tap-bodies
test-tap-bodies: $(BUILD)/ocean-tap $(BUILD)/oceand
	@tests/tap/bodies.sh $(BUILD)

config-doc: $(BUILD)/gen-config-doc $(BUILD)/oceand
	@scripts/gen-config-doc.sh --update --daemon $(BUILD)/oceand $(BUILD)/gen-config-doc

# ---- install ---------------------------------------------------------------

install: $(BUILD)/oceand $(BUILD)/ocean-tap $(WEB_BUILD)/index.html
	install -d $(DESTDIR)$(BINDIR) $(DESTDIR)$(WEBDIR) $(DESTDIR)$(UNITDIR)
	install -m 755 $(BUILD)/oceand $(BUILD)/ocean-tap $(DESTDIR)$(BINDIR)/
	cp -R $(WEB_BUILD)/. $(DESTDIR)$(WEBDIR)/
	chmod -R u=rwX,go=rX $(DESTDIR)$(WEBDIR)
	sed -e 's|@BINDIR@|$(BINDIR)|g' -e 's|@WEBDIR@|$(WEBDIR)|g' \
	    docker/oceand.service > $(DESTDIR)$(UNITDIR)/oceand.service
	chmod 644 $(DESTDIR)$(UNITDIR)/oceand.service

uninstall:
	rm -f $(DESTDIR)$(BINDIR)/oceand $(DESTDIR)$(BINDIR)/ocean-tap $(DESTDIR)$(UNITDIR)/oceand.service
	rm -rf $(DESTDIR)$(PREFIX)/share/oceand
