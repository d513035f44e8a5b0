# mk/web.mk — the browser client: bundle, playwright tests, decode+upload bench.
# web/node_modules comes from `npm ci` (scripts/deps.sh, from web/package-lock.json).

WEB_SRC := web/index.html web/build.mjs $(wildcard web/src/*.js web/src/*.css) proto/js/oc_decode.js proto/js/oc_wasm.js \
           $(BUILD)/wasm/oc_kernels.wasm

BINS += $(BUILD)/web/index.html

$(BUILD)/web/index.html: $(WEB_SRC) web/node_modules/.package-lock.json
	node web/build.mjs $(BUILD)/web $(BUILD)/wasm/oc_kernels.wasm

# npm ci writes node_modules/.package-lock.json; run deps.sh when it is missing.
web/node_modules/.package-lock.json: web/package-lock.json
	@scripts/deps.sh && touch $@

.PHONY: test-web test-web-bodies bench-web
TESTS   += test-web test-web-bodies
BENCHES += bench-web

test-web: $(BUILD)/web/index.html $(BUILD)/oceand $(BUILD)/ocean-tap
	node tests/web/test_web.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web --out $(BUILD)/web-test

# Bodies on the shared sea: two pages, one boat (tests/web/test_bodies.mjs; writes bodies.png).
test-web-bodies: $(BUILD)/web/index.html $(BUILD)/oceand
	node tests/web/test_bodies.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web --out $(BUILD)/web-test

bench-web: $(BUILD)/web/index.html $(BUILD)/oceand
	node bench/web_bench.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web

# `make screenshots`: the gallery (docs/gallery/*.png) and docs/screenshot.png from a real
# daemon in headless chromium (tests/web/screenshots.mjs; ~3 min in software GL).
# `make measure-repetition`: luminance autocorrelation of a top-down view at the patch
# period, with and without the hex-tiled far field (tests/web/repetition.mjs).
.PHONY: screenshots measure-repetition
screenshots: $(BUILD)/web/index.html $(BUILD)/oceand
	node tests/web/screenshots.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web --out docs/gallery --shot docs/screenshot.png

measure-repetition: $(BUILD)/web/index.html $(BUILD)/oceand
	node tests/web/repetition.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web --query '&hex=0' --runs 5
	node tests/web/repetition.mjs --oceand $(BUILD)/oceand --web-root $(BUILD)/web --runs 5
