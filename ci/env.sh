# Sourced by the ci scripts: point Dr.Jit at libLLVM 19 when several LLVMs are installed.
for f in /usr/lib/*/libLLVM.so.19* /usr/lib/*/libLLVM-19.so; do
  if [ -e "$f" ]; then export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-$f}; break; fi
done
