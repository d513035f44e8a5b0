# mk/tools.mk — tools for remote programs and operators:
#   build/ocean-tap           command-line client (tools/)
#   build/gen-config-doc      prints the configuration reference from the params table
#   make install              PREFIX (default /usr/local) and DESTDIR honoured
#   make config-doc           rewrite the reference in README.md
#   test-tap                  ocean-tap + the Python example against a real daemon
#   test-ops                  docker/ <-> apt list, install, configuration reference

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

TAP_OBJS := $(addprefix $(BUILD)/obj/tools/,ocean-tap.o tap_frame.o tap_write.o)

BINS  += $(BUILD)/ocean-tap $(BUILD)/gen-config-doc
TESTS += test-tap test-ops

$(BUILD)/ocean-tap: $(TAP_OBJS) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $(TAP_OBJS) $(PROTO_LIB) $(PKG_LIBS)

$(BUILD)/gen-config-doc: $(BUILD)/obj/scripts/gen-config-doc.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

# ---- tests (budget: < 90 s together) -------------------------------------
.PHONY: test-tap test-ops config-doc install uninstall
test-tap: $(BUILD)/ocean-tap $(BUILD)/oceand
	@tests/tap/run.sh $(BUILD)

test-ops: $(BUILD)/gen-config-doc $(BUILD)/oceand $(BUILD)/ocean-tap $(WEB_BUILD)/index.html
	@tests/tap/ops.sh $(BUILD)

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
