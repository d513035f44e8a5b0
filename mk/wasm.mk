# mk/wasm.mk — the web decoder's WebAssembly kernels (proto/wasm/: raw DEFLATE, codec 3's prediction in SIMD), built with
# Debian's clang (target wasm32) and wasm-ld (package lld): freestanding C, no libc, nothing
# downloaded. The web bundle embeds build/wasm/oc_kernels.wasm (web/build.mjs); proto/js/oc_wasm.js
# loads it. The same C is built natively for its differential fuzzer (fuzz/fuzz_inflate.c).

WASM_CC      := clang
WASM_FLAGS   := --target=wasm32 -O3 -std=c11 -ffreestanding -nostdlib -mbulk-memory -msimd128 $(WARN) \
                -Wl,--no-entry -Wl,--export=__heap_base \
                -Wl,--export=oc_inflate_raw -Wl,--export=oc_inflate_scratch_size \
                -Wl,--export=oc_temporal_predict -Wl,--export=oc_unpack_pairs
WASM_SRCS    := $(wildcard proto/wasm/*.c)

BINS += $(BUILD)/wasm/oc_kernels.wasm

$(BUILD)/wasm/oc_kernels.wasm: $(WASM_SRCS) $(wildcard proto/wasm/*.h)
	@mkdir -p $(dir $@)
	$(WASM_CC) $(WASM_FLAGS) $(WASM_SRCS) -o $@
