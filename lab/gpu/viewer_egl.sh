#!/usr/bin/env bash
# The viewer on a lent GPU machine: headless on EGL with the machine's driver, the neural view
# live while the camera moves. The machine has no GL packages: their wheels (cp312) are carried
# in lab/gpu/wheels (pip download --only-binary=:all: --python-version 3.12 moderngl glcontext
# moderngl-window pyglet trimesh fast-simplification psutil tqdm Pillow, each installed only
# where the machine lacks it).
set -u
mkdir -p /tmp/pk /tmp/extra
ln -sfn "$PWD" /tmp/pk/panogrf
python3 -m pip install -q --no-deps --no-index --target /tmp/extra \
  lab/gpu/wheels/moderngl-*.whl lab/gpu/wheels/glcontext-*.whl \
  lab/gpu/wheels/moderngl_window-*.whl lab/gpu/wheels/pyglet-*.whl lab/gpu/wheels/pyglm-*.whl
for mod in PIL:pillow trimesh:trimesh fast_simplification:fast_simplification psutil:psutil \
  tqdm:tqdm; do
  python3 -c "import ${mod%%:*}" 2>/dev/null || python3 -m pip install -q --no-deps --no-index \
    --target /tmp/extra lab/gpu/wheels/${mod##*:}-*.whl
done
# libglvnd's EGL and OpenGL dispatch (the machine has NVIDIA's EGL vendor library and its
# glvnd JSON, not the dispatch libraries): carried from a Debian 12 machine.
mkdir -p /tmp/gl && cp lab/gpu/wheels/gl/* /tmp/gl/ && (cd /tmp/gl &&
  ln -sf libEGL.so.1.1.0 libEGL.so.1 && ln -sf libEGL.so.1 libEGL.so &&
  ln -sf libGLdispatch.so.0.0.0 libGLdispatch.so.0 && ln -sf libOpenGL.so.0.0.0 libOpenGL.so.0 &&
  ln -sf libOpenGL.so.0 libGL.so)
export PYTHONPATH=/tmp/pk:/tmp/extra LD_LIBRARY_PATH=/tmp/gl:${LD_LIBRARY_PATH:-}
ls /usr/share/glvnd/egl_vendor.d/ 2>&1; ldconfig -p | grep -E "libEGL|nvidia-eglcore" | head -5
python3 -c "
from panogrf.renderer.gl_preview import create_headless_context
ctx = create_headless_context()
print('EGL context:', ctx.info['GL_VENDOR'], '|', ctx.info['GL_RENDERER'], '|', ctx.info['GL_VERSION'])
" 2>&1 | tail -3
for live in on off; do
  echo "=== view, live $live"
  timeout 120 python3 -m panogrf.app.cli view assets/demo --window headless --device cuda \
    --live $live --size 1024x512 --script "wait*60,w*240" --frames 300 \
    --cache-dir /tmp/viewcache 2>&1 | grep -E "renderer:|vendor:|closed after|Error|error" | tail -4
done
