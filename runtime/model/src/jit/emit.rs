//! Expression graphs to native code with Cranelift.
//!
//! Every generated function has the signature `extern "C" fn(*const Args)` and is one basic
//! block, apart from the branches around the calls a continuous axis within its first turn
//! does without (below): it loads the pointers it needs from the argument block, computes the live nodes of its
//! graph in the order the effects first need them (so a value is computed next to its use and
//! register pressure stays local), and stores into `out` and `jac`. It reads and writes memory
//! only at the fixed offsets the graph names, which `lower::validate` and the safe API in
//! `mod.rs` keep inside the buffers.
//!
//! `sin`/`cos` go through one imported `libm::sincos` call per argument and `%` through
//! `libm::fmod`, so the generated code and the interpreter agree bit for bit on them. Two
//! calls are skipped where their result is known exactly: `fmod(a, m)` when `|a| < |m|` (it is
//! `a`), and `sincos` of a value that has the bits of one whose `sincos` was already taken.
//!
//! A graph can also be compiled for two poses a call ([`Width::Pair`]): every value is an
//! `f64x2` whose lanes are the two poses, each operation the one-pose operation lane by lane
//! (the same IEEE roundings, so each lane has the one-pose bits), the calls made per lane,
//! the branches taken only when both lanes agree, and each lane's results stored in its own
//! pose's buffers. The batches of errors use it; the error-and-Jacobian batches do not (on
//! the 5-axis example a two-pose Jacobian code with shuffled pairs of entries was 39 KB
//! against 27 KB, more than the first-level instruction cache, and ran at 0.73× (six rows)
//! and 0.9× (position rows) the one-pose code per pose; the error code at 1.45×), so its
//! Jacobian entries are emitted in the plainest exact form, for the tests.

use std::mem::offset_of;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use cranelift_codegen::control::ControlPlane;
use cranelift_codegen::ir::condcodes::{FloatCC, IntCC};
use cranelift_codegen::ir::{
    types, AbiParam, BlockArg, ConstantData, Endianness, InstBuilder, MemFlagsData, StackSlotData,
    StackSlotKind, UserFuncName, Value,
};
use cranelift_codegen::isa::TargetIsa;
use cranelift_codegen::settings::{self, Configurable};
use cranelift_codegen::Context;
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{default_libcall_names, FuncId, Linkage, Module, ModuleReloc};

use super::graph::{Cmp, Dst, Effect, Graph, Id, Node, Src};
use super::JitError;

/// The argument block of every generated function. Pointers may dangle for arrays the function
/// does not read (an empty slice's pointer); the others point at buffers at least as long as
/// the graph's largest index, which the safe API checks before each call.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub(super) struct Args {
    pub q: *const f64,
    pub inputs: *const f64,
    pub lags: *const f64,
    pub dirs: *const f64,
    pub beta: *const f64,
    pub nonlinear: *const f64,
    /// 12 values: the selected tool's offset rotation (row-major) and translation.
    pub tool_tf: *const f64,
    pub out: *mut f64,
    pub jac: *mut f64,
    pub time: f64,
    pub tool: u64,
}

/// A generated function. Calling it is only sound with an `Args` whose buffers are long enough
/// (see `JitModel::call` in `mod.rs`); a function of [`Width::Pair`] takes a pointer to two
/// consecutive `Args`, one per pose.
pub(super) type RawFn = unsafe extern "C" fn(*const Args);

/// How many poses one call of a generated function evaluates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Width {
    /// One pose, `Args` for it.
    Pose,
    /// Two poses in the two lanes of every value (`f64x2`): the same operations, each rounded
    /// as the one-pose code rounds it, so each lane's results are the one-pose results bit for
    /// bit. The argument is `[Args; 2]`; `beta` and `nonlinear` are read from the first only.
    Pair,
}

/// The `sin`/`cos` of two arguments, as [`kin_jit_sincos`] gives each: `out` receives
/// `sin a, sin b, cos a, cos b`, so each pair of results is one two-lane value.
extern "C" fn kin_jit_sincos2(a: f64, b: f64, out: *mut f64) {
    let ((sa, ca), (sb, cb)) = (libm::sincos(a), libm::sincos(b));
    // SAFETY: only generated code calls this, always with the address of its own 32-byte,
    // 8-aligned stack slot (`Emitter::emit`), so the four writes are in bounds and aligned.
    unsafe {
        out.write(sa);
        out.add(1).write(sb);
        out.add(2).write(ca);
        out.add(3).write(cb);
    }
}

/// The `sin`/`cos` the generated code calls: both values from one argument reduction, written
/// to `out[0]`, `out[1]`.
extern "C" fn kin_jit_sincos(x: f64, out: *mut f64) {
    let (s, c) = libm::sincos(x);
    // SAFETY: only generated code calls this, always with the address of its own 16-byte,
    // 8-aligned stack slot (`Emitter::emit`), so both writes are in bounds and aligned.
    unsafe {
        out.write(s);
        out.add(1).write(c);
    }
}

/// `a % b` for the continuous-axis reduction (`f64::rem_euclid`); fmod is exact, so this
/// agrees with Rust's `%` bit for bit.
extern "C" fn kin_jit_fmod(a: f64, b: f64) -> f64 {
    libm::fmod(a, b)
}

const SINCOS: &str = "kin_jit_sincos";
const SINCOS2: &str = "kin_jit_sincos2";
const FMOD: &str = "kin_jit_fmod";

fn codegen(e: impl std::fmt::Display) -> JitError {
    JitError::Codegen {
        message: e.to_string(),
    }
}

/// A JIT module holding the compiled functions, in the order of the graphs given.
pub(super) struct Emitted {
    pub module: JITModule,
    pub functions: Vec<*const u8>,
}

/// Compiles `graphs` (name, graph) into one module. With `dump`, the Cranelift IR of each
/// function and the machine code it became are appended to it ([`super::dump_clif`]).
pub(super) fn compile(
    graphs: &[(String, &Graph)],
    width: Width,
    mut dump: Option<&mut String>,
) -> Result<Emitted, JitError> {
    let mut flags = settings::builder();
    // The JIT links by absolute address (crate notes: is_pic=false, no colocated libcalls).
    flags
        .set("use_colocated_libcalls", "false")
        .map_err(codegen)?;
    flags.set("is_pic", "false").map_err(codegen)?;
    // The graph is already value-numbered and constant-folded, and its effect order is a
    // schedule: each component's column and the running sums die right after use. Cranelift's
    // e-graph pass (`speed`) re-places every pure instruction at its first use, which stretches
    // those live ranges across the function: on the 5-axis example it made twice the spills
    // and took 1.6× the compile time, for slower code.
    flags.set("opt_level", "none").map_err(codegen)?;
    // The graphs are straight-line code built by one routine; re-verifying them on every model
    // costs compile time. Debug builds (and so the tests) keep the verifier.
    flags
        .set(
            "enable_verifier",
            if cfg!(debug_assertions) {
                "true"
            } else {
                "false"
            },
        )
        .map_err(codegen)?;
    let isa = cranelift_native::builder()
        .map_err(|m| JitError::Host {
            message: m.to_string(),
        })?
        .finish(settings::Flags::new(flags))
        .map_err(codegen)?;
    if isa.pointer_bytes() != 8 {
        return Err(JitError::Host {
            message: "the JIT needs a 64-bit target".into(),
        });
    }
    let mut jb = JITBuilder::with_isa(isa.clone(), default_libcall_names());
    jb.symbol(
        SINCOS,
        kin_jit_sincos as extern "C" fn(f64, *mut f64) as *const u8,
    );
    jb.symbol(
        SINCOS2,
        kin_jit_sincos2 as extern "C" fn(f64, f64, *mut f64) as *const u8,
    );
    jb.symbol(
        FMOD,
        kin_jit_fmod as extern "C" fn(f64, f64) -> f64 as *const u8,
    );
    let mut module = JITModule::new(jb);

    let result = define_all(&mut module, &*isa, graphs, width, &mut dump);
    let ids = match result {
        Ok(ids) => ids,
        Err(e) => {
            // SAFETY: nothing from this module was handed out: no pointer into it exists.
            unsafe { module.free_memory() };
            return Err(e);
        }
    };
    if let Err(e) = module.finalize_definitions() {
        // SAFETY: as above, no function pointer was taken yet.
        unsafe { module.free_memory() };
        return Err(codegen(e));
    }
    let functions = ids
        .iter()
        .map(|id| module.get_finalized_function(*id))
        .collect();
    Ok(Emitted { module, functions })
}

/// One function's machine code, ready to be placed in the module.
struct Compiled {
    alignment: u64,
    code: Vec<u8>,
    relocs: Vec<ModuleReloc>,
    /// The Cranelift IR and the machine code as text, for a dump.
    text: Option<String>,
}

/// Declares the functions of `graphs` in `module`, compiles them on up to
/// [`compile_threads`] threads, and defines them in the order given (so the code is laid out
/// as a single thread lays it out, whatever thread compiled what).
///
/// The register allocator is most of the compile time and each function is compiled on its
/// own, so the functions are shared out among threads, largest first. Only building a
/// function's IR touches the module (to import the three routines it calls), briefly under a
/// lock; the compilation needs only the ISA.
fn define_all(
    module: &mut JITModule,
    isa: &dyn TargetIsa,
    graphs: &[(String, &Graph)],
    width: Width,
    dump: &mut Option<&mut String>,
) -> Result<Vec<FuncId>, JitError> {
    let ptr = module.target_config().pointer_type();
    let config = module.target_config();
    let mut sincos_sig = module.make_signature();
    sincos_sig.params.push(AbiParam::new(types::F64));
    sincos_sig.params.push(AbiParam::new(ptr));
    let sincos = module
        .declare_function(SINCOS, Linkage::Import, &sincos_sig)
        .map_err(codegen)?;
    let mut sincos2_sig = module.make_signature();
    sincos2_sig.params.push(AbiParam::new(types::F64));
    sincos2_sig.params.push(AbiParam::new(types::F64));
    sincos2_sig.params.push(AbiParam::new(ptr));
    let sincos2 = module
        .declare_function(SINCOS2, Linkage::Import, &sincos2_sig)
        .map_err(codegen)?;
    let mut fmod_sig = module.make_signature();
    fmod_sig.params.push(AbiParam::new(types::F64));
    fmod_sig.params.push(AbiParam::new(types::F64));
    fmod_sig.returns.push(AbiParam::new(types::F64));
    let fmod = module
        .declare_function(FMOD, Linkage::Import, &fmod_sig)
        .map_err(codegen)?;

    let mut sig = module.make_signature();
    sig.params.push(AbiParam::new(ptr));
    let ids = graphs
        .iter()
        .map(|(name, _)| {
            module
                .declare_function(name, Linkage::Local, &sig)
                .map_err(codegen)
        })
        .collect::<Result<Vec<FuncId>, JitError>>()?;

    // Largest first, so that no thread is left with a long function at the end.
    let mut order: Vec<usize> = (0..graphs.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(graphs.get(i).map_or(0, |(_, g)| g.nodes().len())));
    let next = AtomicUsize::new(0);
    let disasm = dump.is_some();
    let shared = Mutex::new(&mut *module);
    // One thread's share: take the next function in `order` until none is left.
    let work = || -> Vec<(usize, Result<Compiled, JitError>)> {
        let mut ctx = Context::new();
        let mut fctx = FunctionBuilderContext::new();
        let mut done = Vec::new();
        while let Some(&i) = order.get(next.fetch_add(1, Ordering::Relaxed)) {
            let (Some((name, graph)), Some(&id)) = (graphs.get(i), ids.get(i)) else {
                break;
            };
            ctx.clear();
            ctx.func.signature = sig.clone();
            ctx.func.name = UserFuncName::user(0, id.as_u32());
            let imports = {
                let mut m = match shared.lock() {
                    Ok(m) => m,
                    // Declaring an import cannot leave the module half-changed.
                    Err(poisoned) => poisoned.into_inner(),
                };
                Imports {
                    sincos: m.declare_func_in_func(sincos, &mut ctx.func),
                    sincos2: m.declare_func_in_func(sincos2, &mut ctx.func),
                    fmod: m.declare_func_in_func(fmod, &mut ctx.func),
                }
            };
            emit_function(&mut ctx, &mut fctx, graph, &imports, width, ptr, config);
            done.push((i, compile_one(&mut ctx, isa, id, name, disasm)));
        }
        done
    };
    let threads = compile_threads(graphs.len());
    let mut results: Vec<Option<Result<Compiled, JitError>>> =
        std::iter::repeat_with(|| None).take(graphs.len()).collect();
    let mut place = |done: Vec<(usize, Result<Compiled, JitError>)>| {
        for (i, r) in done {
            if let Some(slot) = results.get_mut(i) {
                *slot = Some(r);
            }
        }
    };
    if threads <= 1 {
        place(work());
    } else {
        std::thread::scope(|scope| {
            let helpers: Vec<_> = (1..threads).map(|_| scope.spawn(work)).collect();
            place(work());
            for helper in helpers {
                match helper.join() {
                    Ok(done) => place(done),
                    // Cranelift panicked on a helper thread: panic here, as it would have had
                    // it run on this one.
                    Err(payload) => std::panic::resume_unwind(payload),
                }
            }
        });
    }

    for ((id, result), (name, _)) in ids.iter().zip(results).zip(graphs) {
        let compiled = result.ok_or_else(|| JitError::Codegen {
            message: format!("{name}: not compiled"),
        })??;
        module
            .define_function_bytes(*id, compiled.alignment, &compiled.code, &compiled.relocs)
            .map_err(|e| JitError::Codegen {
                message: format!("{name}: {e:?}"),
            })?;
        if let (Some(d), Some(text)) = (dump.as_deref_mut(), compiled.text) {
            d.push_str(&text);
        }
    }
    Ok(ids)
}

/// Threads to compile `functions` functions on: one per core the process may use, at most
/// one per function.
fn compile_threads(functions: usize) -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(functions)
}

/// Compiles the function built in `ctx` (what `JITModule::define_function` does before it
/// copies the code into the module).
fn compile_one(
    ctx: &mut Context,
    isa: &dyn TargetIsa,
    id: FuncId,
    name: &str,
    disasm: bool,
) -> Result<Compiled, JitError> {
    let mut text = disasm.then(|| format!("; {name}\n{}\n", ctx.func.display()));
    ctx.set_disasm(disasm);
    ctx.compile(isa, &mut ControlPlane::default())
        .map_err(|e| JitError::Codegen {
            message: format!("{name}: {:?}", e.inner),
        })?;
    // Read back through a shared borrow: the relocations need the function too.
    let compiled = ctx.compiled_code().ok_or_else(|| JitError::Codegen {
        message: format!("{name}: no code"),
    })?;
    let alignment = u64::from(compiled.buffer.alignment);
    let code = compiled.code_buffer().to_vec();
    if let (Some(t), Some(vcode)) = (text.as_mut(), compiled.vcode.as_deref()) {
        t.push_str(&format!(
            "; {name}: machine code, {} bytes\n{vcode}\n",
            code.len()
        ));
    }
    let relocs = compiled
        .buffer
        .relocs()
        .iter()
        .map(|r| ModuleReloc::from_mach_reloc(r, &ctx.func, id))
        .collect();
    Ok(Compiled {
        alignment,
        code,
        relocs,
        text,
    })
}

struct Imports {
    sincos: cranelift_codegen::ir::FuncRef,
    sincos2: cranelift_codegen::ir::FuncRef,
    fmod: cranelift_codegen::ir::FuncRef,
}

/// Byte offset of lane `lane`'s argument block in a [`Width::Pair`] function's argument.
fn lane_args(lane: u8) -> i32 {
    // Two blocks of a handful of words.
    (usize::from(lane) * std::mem::size_of::<Args>()) as i32
}

/// Byte offset of an argument-block field.
fn field(src: Src) -> i32 {
    let o = match src {
        Src::Q => offset_of!(Args, q),
        Src::Inputs => offset_of!(Args, inputs),
        Src::Lags => offset_of!(Args, lags),
        Src::Dirs => offset_of!(Args, dirs),
        Src::Beta => offset_of!(Args, beta),
        Src::Nonlinear => offset_of!(Args, nonlinear),
        Src::ToolTf => offset_of!(Args, tool_tf),
        Src::Time => offset_of!(Args, time),
        Src::Out => offset_of!(Args, out),
    };
    // The block is a handful of words.
    o as i32
}

fn dst_field(dst: Dst) -> i32 {
    (match dst {
        Dst::Out => offset_of!(Args, out),
        Dst::Jac => offset_of!(Args, jac),
    }) as i32
}

/// Byte offset of element `index` of an f64 array; `validate` bounds it far below `i32::MAX`.
fn elem(index: u32) -> i32 {
    i32::try_from(u64::from(index) * 8).unwrap_or(i32::MAX)
}

fn emit_function(
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    graph: &Graph,
    imports: &Imports,
    width: Width,
    ptr: types::Type,
    config: cranelift_codegen::isa::TargetFrontendConfig,
) {
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let block = b.create_block();
    b.append_block_params_for_function_params(block);
    b.switch_to_block(block);
    let args = b.block_params(block).first().copied();
    let mut e = Emitter {
        graph,
        width,
        values: vec![None; graph.nodes().len()],
        bases: Default::default(),
        tool: None,
        args,
        splats: Default::default(),
        slots: Default::default(),
        lanes: Default::default(),
        ptr,
        imports,
    };
    // Calls first: the C calling convention saves no float register across a call, so every
    // value live at a call is spilled. At the top only the calls' own inputs and results are.
    let live = graph.live();
    for (i, node) in graph.nodes().iter().enumerate() {
        if live.get(i).copied().unwrap_or(false)
            && matches!(node, Node::Sin(_) | Node::Cos(_) | Node::Fmod(..))
        {
            e.prepare(&mut b, Id::new(i));
        }
    }
    // The entries that are zero whatever the pose, all at once from one cleared register,
    // where each cleared a register of its own among the products (191 of the 588 stores of
    // the 5-axis example's six-row function: 143 pairs and 48 single entries).
    let zeros = match width {
        Width::Pose => e.zero_entries(),
        Width::Pair => Vec::new(),
    };
    e.store_zeros(&mut b, &zeros);
    let mut skip = zeros.iter().map(|z| z.at).peekable();
    for (at, &effect) in graph.effects().iter().enumerate() {
        if skip.next_if_eq(&at).is_some() {
            continue;
        }
        match effect {
            Effect::Eval(value) => {
                e.prepare(&mut b, value);
            }
            Effect::Store(dst, index, value) => {
                if let Some(v) = e.value(&mut b, value) {
                    e.store_lanes(&mut b, dst, index, v);
                }
            }
            Effect::AddTo(dst, index, value) => {
                if let Some(v) = e.value(&mut b, value) {
                    e.add_to_lanes(&mut b, dst, index, v);
                }
            }
            Effect::Pair(dst, index, col, x, y) => match width {
                Width::Pose => {
                    let v = e.pair(&mut b, col, x, y);
                    let base = e.base_ptr(&mut b, 0, dst_field(dst));
                    if let (Some(v), Some(base)) = (v, base) {
                        // The buffer is only 8-byte aligned: a 16-byte store without `aligned`.
                        b.ins()
                            .store(MemFlagsData::new().with_notrap(), v, base, elem(index));
                    }
                }
                Width::Pair => {
                    e.pair_of_poses(&mut b, dst, index, col, x, y);
                }
            },
        }
    }
    b.ins().return_(&[]);
    b.seal_all_blocks();
    b.finalize(config);
}

/// A Jacobian entry (or pair of entries) that is zero whatever the pose: see
/// [`Emitter::zero_entries`].
struct Zero {
    /// The position of its effect among the graph's.
    at: usize,
    index: u32,
    pair: bool,
}

struct Emitter<'g> {
    graph: &'g Graph,
    width: Width,
    values: Vec<Option<Value>>,
    /// Pointers loaded from the argument block, by lane and field offset.
    bases: rustc_hash::FxHashMap<(u8, i32), Value>,
    /// The selected tool: an `i64`, or for two poses an `i64x2`.
    tool: Option<Value>,
    args: Option<Value>,
    /// Each column entry's two-lane splat, made once and used by every pair of its component.
    splats: rustc_hash::FxHashMap<Id, Value>,
    /// Results of `sincos` calls: the slot and offset each is read from.
    slots: rustc_hash::FxHashMap<Id, (cranelift_codegen::ir::StackSlot, i32)>,
    lanes: rustc_hash::FxHashMap<(Id, Id), Value>,
    ptr: types::Type,
    imports: &'g Imports,
}

/// Flags of a bitcast between vector types: lane order as in memory, which on x86-64 is a
/// no-op on the register.
fn vector_cast() -> MemFlagsData {
    MemFlagsData::new().with_endianness(Endianness::Little)
}

impl Emitter<'_> {
    /// The type of every value: one `f64`, or one `f64` per pose.
    fn ty(&self) -> types::Type {
        match self.width {
            Width::Pose => types::F64,
            Width::Pair => types::F64X2,
        }
    }

    /// The lanes (poses) a value has.
    fn lane_count(&self) -> u8 {
        match self.width {
            Width::Pose => 1,
            Width::Pair => 2,
        }
    }

    fn base_ptr(&mut self, b: &mut FunctionBuilder, lane: u8, offset: i32) -> Option<Value> {
        if let Some(v) = self.bases.get(&(lane, offset)) {
            return Some(*v);
        }
        let v = b.ins().load(
            self.ptr,
            MemFlagsData::trusted(),
            self.args?,
            lane_args(lane) + offset,
        );
        self.bases.insert((lane, offset), v);
        Some(v)
    }

    fn get(&self, id: Id) -> Option<Value> {
        self.values.get(id.index()).copied().flatten()
    }

    fn set(&mut self, id: Id, v: Value) {
        if let Some(slot) = self.values.get_mut(id.index()) {
            *slot = Some(v);
        }
    }

    /// `v` in every lane: an `f64` constant, or a two-lane constant.
    fn constant(&self, b: &mut FunctionBuilder, v: f64) -> Value {
        match self.width {
            Width::Pose => b.ins().f64const(v),
            Width::Pair => {
                let bytes: Vec<u8> = [v.to_le_bytes(), v.to_le_bytes()].concat();
                let c = b.func.dfg.constants.insert(ConstantData::from(bytes));
                b.ins().vconst(types::F64X2, c)
            }
        }
    }

    /// The scalars `lanes` (one per pose) as one value of [`Emitter::ty`].
    fn join(&self, b: &mut FunctionBuilder, lanes: &[Value]) -> Option<Value> {
        match (self.width, lanes) {
            (Width::Pose, [v]) => Some(*v),
            (Width::Pair, [x, y]) => Some(self.join_pair(b, *x, *y)),
            _ => None,
        }
    }

    /// Lane `lane` of `v` as a scalar.
    fn lane(&self, b: &mut FunctionBuilder, v: Value, lane: u8) -> Value {
        match self.width {
            Width::Pose => v,
            Width::Pair => b.ins().extractlane(v, lane),
        }
    }

    /// The value of operand `id`. Constants are not kept in registers: each use gets its own
    /// `f64const`, which the backend folds into the instruction as a constant-pool operand
    /// (or a register clear for 0), instead of holding it live (and spilling it) across the
    /// function.
    fn operand(&mut self, b: &mut FunctionBuilder, id: Id) -> Option<Value> {
        if let Some(&(slot, offset)) = self.slots.get(&id) {
            return Some(b.ins().stack_load(self.ptr, self.ty(), slot, offset));
        }
        // A column's scalar uses after its splat read the splat's first lane, the same
        // register: the scalar dies where the splat is made instead of holding a register of
        // its own (or a spill and its reloads) through the rest of the component.
        if let (Width::Pose, Some(&splat)) = (self.width, self.splats.get(&id)) {
            return Some(b.ins().extractlane(splat, 0));
        }
        match self.graph.node(id) {
            Node::Const(bits) => Some(self.constant(b, f64::from_bits(bits))),
            _ => self.get(id),
        }
    }

    /// Whether `id` needs no emitting: done already, a constant, or a result in a slot.
    fn available(&self, id: Id) -> bool {
        self.get(id).is_some()
            || self.slots.contains_key(&id)
            || matches!(self.graph.node(id), Node::Const(_))
    }

    /// Stores each lane of `v` at `dst[index]` of its pose.
    fn store_lanes(&mut self, b: &mut FunctionBuilder, dst: Dst, index: u32, v: Value) {
        let flags = MemFlagsData::trusted();
        for lane in 0..self.lane_count() {
            let x = self.lane(b, v, lane);
            if let Some(base) = self.base_ptr(b, lane, dst_field(dst)) {
                b.ins().store(flags, x, base, elem(index));
            }
        }
    }

    /// `dst[index] += v` for each pose.
    fn add_to_lanes(&mut self, b: &mut FunctionBuilder, dst: Dst, index: u32, v: Value) {
        let flags = MemFlagsData::trusted();
        for lane in 0..self.lane_count() {
            let x = self.lane(b, v, lane);
            if let Some(base) = self.base_ptr(b, lane, dst_field(dst)) {
                let old = b.ins().load(types::F64, flags, base, elem(index));
                let sum = b.ins().fadd(old, x);
                b.ins().store(flags, sum, base, elem(index));
            }
        }
    }

    /// `[col·x, col·y]` as one two-lane product: the same two roundings as two scalar
    /// products. Splats and lane pairs are shared between the six rows of a coefficient pair.
    fn pair(&mut self, b: &mut FunctionBuilder, col: Id, x: Id, y: Id) -> Option<Value> {
        if self.graph.value(col) == Some(0.0) {
            // A register clear, rematerialised at each use like the scalar constants.
            return Some(self.zero_pair(b));
        }
        // Each splat is a value of its own, made once, which the register allocator keeps or
        // spills. It was kept in a stack area and read as a memory operand of each multiply
        // instead; those reads, interleaved with the Jacobian's stores, waited on the stores
        // whenever the output buffer lay at certain offsets from the stack (4 KiB aliasing):
        // 7–21 % slower per pose at a few of the offsets tried (2 of 32 in one process, 1 of 8
        // in another), at none with the splats as values, and no faster at the others.
        let splat = match self.splats.get(&col) {
            Some(v) => *v,
            None => {
                let c = self.value(b, col)?;
                let v = b.ins().splat(types::F64X2, c);
                self.splats.insert(col, v);
                v
            }
        };
        let lanes = match self.lanes.get(&(x, y)) {
            Some(v) => *v,
            None => {
                let (xv, yv) = (self.value(b, x)?, self.value(b, y)?);
                let v = self.join_pair(b, xv, yv);
                self.lanes.insert((x, y), v);
                v
            }
        };
        Some(b.ins().fmul(splat, lanes))
    }

    /// The Jacobian entries that are a constant +0 whatever the pose (a [`Effect::Store`] of
    /// it, or a [`Effect::Pair`] whose column is zero): each effect's position among the
    /// graph's, where it stores, and whether it is a pair. Storing them anywhere else in the
    /// function changes nothing: every Jacobian entry is written once (a test holds it), and
    /// no generated code reads the Jacobian.
    fn zero_entries(&self) -> Vec<Zero> {
        let g = self.graph;
        g.effects()
            .iter()
            .enumerate()
            .filter_map(|(at, &effect)| match effect {
                Effect::Store(Dst::Jac, index, v) if g.value(v).map(f64::to_bits) == Some(0) => {
                    Some(Zero {
                        at,
                        index,
                        pair: false,
                    })
                }
                Effect::Pair(Dst::Jac, index, col, ..) if g.value(col) == Some(0.0) => Some(Zero {
                    at,
                    index,
                    pair: true,
                }),
                _ => None,
            })
            .collect()
    }

    /// Stores `zeros` from one cleared register for the single entries and one for the pairs.
    fn store_zeros(&mut self, b: &mut FunctionBuilder, zeros: &[Zero]) {
        // No zeros, no load of the Jacobian's pointer (the error functions have none).
        if zeros.is_empty() {
            return;
        }
        let Some(base) = self.base_ptr(b, 0, dst_field(Dst::Jac)) else {
            return;
        };
        let (mut single, mut pair) = (None, None);
        for z in zeros {
            let v = if z.pair {
                *pair.get_or_insert_with(|| self.zero_pair(b))
            } else {
                *single.get_or_insert_with(|| b.ins().f64const(0.0))
            };
            b.ins()
                .store(MemFlagsData::new().with_notrap(), v, base, elem(z.index));
        }
    }

    /// `[x, y]` from two scalars.
    fn join_pair(&self, b: &mut FunctionBuilder, x: Value, y: Value) -> Value {
        // `splat` then `insertlane`: two instructions, where `scalar_to_vector` first clears
        // the upper lane that `insertlane` overwrites anyway.
        let v = b.ins().splat(types::F64X2, x);
        b.ins().insertlane(v, y, 1)
    }

    /// `[0, 0]`, a register clear.
    fn zero_pair(&self, b: &mut FunctionBuilder) -> Value {
        let zero = b
            .func
            .dfg
            .constants
            .insert(ConstantData::from(&[0u8; 16][..]));
        b.ins().vconst(types::F64X2, zero)
    }

    /// Two poses' `[col·x, col·y]`: the products lane by lane and each stored in its pose's
    /// row, the same roundings as [`Emitter::pair`] (a zero `col` stores zeros, as there).
    /// Only the tests build it: the batches keep the Jacobian at one pose a call, which
    /// measured faster (spec/performance.md), so this is the plain form, not a tuned one.
    fn pair_of_poses(
        &mut self,
        b: &mut FunctionBuilder,
        dst: Dst,
        index: u32,
        col: Id,
        x: Id,
        y: Id,
    ) {
        for (at, v) in [(index, x), (index + 1, y)] {
            let product = if self.graph.value(col) == Some(0.0) {
                Some(self.constant(b, 0.0))
            } else {
                match (self.value(b, col), self.value(b, v)) {
                    (Some(c), Some(v)) => Some(b.ins().fmul(c, v)),
                    _ => None,
                }
            };
            if let Some(p) = product {
                self.store_lanes(b, dst, at, p);
            }
        }
    }

    /// The operands `x` (of node `a`) and `y` of a commutative operation, a constant last:
    /// the backend reads a second operand that is a constant from the constant pool inside
    /// the instruction, where a first one is built in a general register and moved over (two
    /// instructions more; 26 of them in the 5-axis example's six-row function). The same
    /// result either way: IEEE addition and multiplication are commutative, and a constant
    /// is never a NaN whose payload the order would choose.
    fn constant_last(&self, a: Id, x: Value, y: Value) -> (Value, Value) {
        if matches!(self.graph.node(a), Node::Const(_)) {
            (y, x)
        } else {
            (x, y)
        }
    }

    /// Emits `root` and whatever it needs ([`Emitter::prepare`]) and gives its value.
    fn value(&mut self, b: &mut FunctionBuilder, root: Id) -> Option<Value> {
        self.prepare(b, root)?;
        self.operand(b, root)
    }

    /// Emits `root` and whatever it needs, depth first without recursion (sums over hundreds
    /// of coefficients make deep operand chains), without reading its value: a `sin` or `cos`
    /// is read from its slot at each use, and a load nothing uses stays in the code (the
    /// backend keeps every load).
    fn prepare(&mut self, b: &mut FunctionBuilder, root: Id) -> Option<()> {
        let mut stack = vec![(root, false)];
        while let Some((id, ready)) = stack.pop() {
            if self.available(id) {
                continue;
            }
            let node = self.graph.node(id);
            if !ready {
                stack.push((id, true));
                for op in super::graph::operands(node) {
                    if !self.available(op) {
                        stack.push((op, false));
                    }
                }
                continue;
            }
            if let Node::Sin(x) | Node::Cos(x) = node {
                self.sincos_node(b, id, x)?;
                continue;
            }
            let v = self.emit(b, node)?;
            self.set(id, v);
        }
        Some(())
    }

    /// The call that gives `sin x` and `cos x` (node `id` is one of them), into a stack slot
    /// of its own. The results stay there and are loaded at each use ([`Emitter::operand`]):
    /// every float register dies at the next call, so holding them in registers would only
    /// add a spill.
    fn sincos_node(&mut self, b: &mut FunctionBuilder, id: Id, x: Id) -> Option<()> {
        let xv = self.operand(b, x)?;
        let size = 16 * u32::from(self.lane_count());
        let slot =
            b.create_sized_stack_slot(StackSlotData::new(StackSlotKind::ExplicitSlot, size, 3));
        self.sincos(b, x, xv, slot)?;
        let cos = self.cos_offset();
        for (node, offset) in [(Node::Sin(x), 0), (Node::Cos(x), cos)] {
            if let Some(n) = self.graph.find(&node) {
                self.slots.insert(n, (slot, offset));
            }
        }
        let offset = if matches!(self.graph.node(id), Node::Sin(_)) {
            0
        } else {
            cos
        };
        self.slots.insert(id, (slot, offset));
        Some(())
    }

    /// `sin x, cos x` into `slot` (sines first, then cosines: at 0 and 8 for one pose, at 0
    /// and 16 for two) by one call, unless `x` usually equals a value whose call came earlier
    /// ([`Graph::usual`]): then, when the bits are equal (in every lane), that call's results
    /// are copied, the same numbers the call would give.
    fn sincos(
        &mut self,
        b: &mut FunctionBuilder,
        x: Id,
        xv: Value,
        slot: cranelift_codegen::ir::StackSlot,
    ) -> Option<()> {
        let earlier = self.graph.usual(x).and_then(|y| {
            let n = self
                .graph
                .find(&Node::Sin(y))
                .or_else(|| self.graph.find(&Node::Cos(y)))?;
            let (from, _) = self.slots.get(&n).copied()?;
            Some((y, from))
        });
        let Some((y, from)) = earlier else {
            self.call_sincos(b, xv, slot);
            return Some(());
        };
        let yv = self.value(b, y)?;
        let same = match self.width {
            Width::Pose => {
                let flags = MemFlagsData::new();
                let (xi, yi) = (
                    b.ins().bitcast(types::I64, flags, xv),
                    b.ins().bitcast(types::I64, flags, yv),
                );
                b.ins().icmp(IntCC::Equal, xi, yi)
            }
            Width::Pair => {
                let (xi, yi) = (
                    b.ins().bitcast(types::I64X2, vector_cast(), xv),
                    b.ins().bitcast(types::I64X2, vector_cast(), yv),
                );
                let lanes = b.ins().icmp(IntCC::Equal, xi, yi);
                b.ins().vall_true(lanes)
            }
        };
        let (copy, call, join) = (b.create_block(), b.create_block(), b.create_block());
        b.ins().brif(same, copy, &[], call, &[]);
        b.switch_to_block(copy);
        let ty = self.ty();
        let half = self.cos_offset();
        for offset in [0, half] {
            let v = b.ins().stack_load(self.ptr, ty, from, offset);
            b.ins().stack_store(self.ptr, v, slot, offset);
        }
        b.ins().jump(join, &[]);
        b.switch_to_block(call);
        self.call_sincos(b, xv, slot);
        b.ins().jump(join, &[]);
        b.switch_to_block(join);
        Some(())
    }

    /// Offset of the cosines in a `sincos` slot (after the sines of every lane).
    fn cos_offset(&self) -> i32 {
        8 * i32::from(self.lane_count())
    }

    fn call_sincos(
        &mut self,
        b: &mut FunctionBuilder,
        xv: Value,
        slot: cranelift_codegen::ir::StackSlot,
    ) {
        let addr = b.ins().stack_addr(self.ptr, slot, 0);
        match self.width {
            Width::Pose => {
                b.ins().call(self.imports.sincos, &[xv, addr]);
            }
            Width::Pair => {
                let (x0, x1) = (self.lane(b, xv, 0), self.lane(b, xv, 1));
                b.ins().call(self.imports.sincos2, &[x0, x1, addr]);
            }
        }
    }

    /// `src[index]` of each pose, one per lane; `beta` and `nonlinear`, the same for both
    /// poses, read once (from the first) into both lanes.
    fn load(&mut self, b: &mut FunctionBuilder, src: Src, index: u32) -> Option<Value> {
        let flags = MemFlagsData::trusted();
        let shared = matches!(src, Src::Beta | Src::Nonlinear);
        let mut lanes = Vec::with_capacity(2);
        for lane in 0..self.lane_count() {
            if shared && lane > 0 {
                break;
            }
            let v = if src == Src::Time {
                b.ins().load(
                    types::F64,
                    flags,
                    self.args?,
                    lane_args(lane) + field(Src::Time),
                )
            } else {
                let base = self.base_ptr(b, lane, field(src))?;
                b.ins().load(types::F64, flags, base, elem(index))
            };
            lanes.push(v);
        }
        match (self.width, lanes.as_slice()) {
            (Width::Pair, [one]) => Some(b.ins().splat(types::F64X2, *one)),
            _ => self.join(b, &lanes),
        }
    }

    /// The selected tool of each pose: an `i64`, or an `i64x2` for two poses.
    fn tool(&mut self, b: &mut FunctionBuilder) -> Option<Value> {
        if let Some(t) = self.tool {
            return Some(t);
        }
        let flags = MemFlagsData::trusted();
        let at = |lane| lane_args(lane) + offset_of!(Args, tool) as i32;
        let t = match self.width {
            Width::Pose => b.ins().load(types::I64, flags, self.args?, at(0)),
            Width::Pair => {
                let t0 = b.ins().load(types::I64, flags, self.args?, at(0));
                let t1 = b.ins().load(types::I64, flags, self.args?, at(1));
                let v = b.ins().splat(types::I64X2, t0);
                b.ins().insertlane(v, t1, 1)
            }
        };
        self.tool = Some(t);
        Some(t)
    }

    fn emit(&mut self, b: &mut FunctionBuilder, node: Node) -> Option<Value> {
        let mut ops = [None; 4];
        for (slot, op) in ops.iter_mut().zip(super::graph::operands(node)) {
            *slot = Some(self.operand(b, op)?);
        }
        let [p, q, r, t] = ops;
        Some(match node {
            Node::Const(bits) => self.constant(b, f64::from_bits(bits)),
            Node::Load(src, i) => self.load(b, src, i)?,
            Node::Add(a, _) => {
                let (x, y) = self.constant_last(a, p?, q?);
                b.ins().fadd(x, y)
            }
            Node::Sub(..) => b.ins().fsub(p?, q?),
            Node::Mul(a, _) => {
                let (x, y) = self.constant_last(a, p?, q?);
                b.ins().fmul(x, y)
            }
            Node::Div(..) => b.ins().fdiv(p?, q?),
            Node::PosPart(_) => {
                // `a` where `0 < a`, else +0 (for a NaN too): written as the comparison and
                // select that the backend turns into one `maxsd` (`maxpd` for two poses),
                // where `(a + |a|)·0.5` took five instructions, the mask of `|a|` built in a
                // general register.
                let a = p?;
                let zero = self.constant(b, 0.0);
                let above = b.ins().fcmp(FloatCC::LessThan, zero, a);
                match self.width {
                    Width::Pose => b.ins().select(above, a, zero),
                    Width::Pair => {
                        let mask = b.ins().bitcast(types::F64X2, vector_cast(), above);
                        b.ins().bitselect(mask, a, zero)
                    }
                }
            }
            // `−a` as `a·(−1)`, the same number (a product by −1 is exact and flips the sign,
            // zeros included), read from the constant pool by one instruction where `fneg`
            // builds its sign mask in a general register and moves it over (three).
            Node::Neg(_) => {
                let minus_one = self.constant(b, -1.0);
                b.ins().fmul(p?, minus_one)
            }
            Node::Floor(_) => b.ins().floor(p?),
            // `prepare` emits these (`sincos_node`): their values are read at each use.
            Node::Sin(_) | Node::Cos(_) => return None,
            Node::Fmod(_, modulus) => {
                // `fmod(a, m)` is `a` itself, exactly, when `|a| < |m|` (a continuous axis
                // within its first turn): the call only where it is not (for two poses, where
                // either is not). A NaN fails the comparison and takes the call, as it would
                // without the test.
                let (a, m) = (p?, q?);
                let ty = self.ty();
                let (call, join) = (b.create_block(), b.create_block());
                let result = b.append_block_param(join, ty);
                let abs_a = b.ins().fabs(a);
                // A constant modulus (a turn, 2π) has its `|m|` known here: no mask to build.
                let abs_m = match self.graph.value(modulus) {
                    Some(c) => self.constant(b, c.abs()),
                    None => b.ins().fabs(m),
                };
                let inside = b.ins().fcmp(FloatCC::LessThan, abs_a, abs_m);
                let inside = match self.width {
                    Width::Pose => inside,
                    Width::Pair => b.ins().vall_true(inside),
                };
                b.ins().brif(inside, join, &[BlockArg::Value(a)], call, &[]);
                b.switch_to_block(call);
                let mut lanes = Vec::with_capacity(2);
                for lane in 0..self.lane_count() {
                    let (al, ml) = (self.lane(b, a, lane), self.lane(b, m, lane));
                    let called = b.ins().call(self.imports.fmod, &[al, ml]);
                    lanes.push(b.inst_results(called).first().copied()?);
                }
                let r = self.join(b, &lanes)?;
                b.ins().jump(join, &[BlockArg::Value(r)]);
                b.switch_to_block(join);
                result
            }
            Node::Select(cmp, ..) => {
                let cc = match cmp {
                    Cmp::Gt => FloatCC::GreaterThan,
                    Cmp::Ge => FloatCC::GreaterThanOrEqual,
                };
                let c = b.ins().fcmp(cc, p?, q?);
                match self.width {
                    Width::Pose => b.ins().select(c, r?, t?),
                    Width::Pair => {
                        // Lane by lane: all ones where the comparison holds.
                        let mask = b.ins().bitcast(types::F64X2, vector_cast(), c);
                        b.ins().bitselect(mask, r?, t?)
                    }
                }
            }
            Node::IfTool(i, _) => {
                let tool = self.tool(b)?;
                let x = p?;
                match self.width {
                    Width::Pose => {
                        let c = b.ins().icmp_imm_u(IntCC::Equal, tool, i64::from(i));
                        let zero = b.ins().f64const(0.0);
                        b.ins().select(c, x, zero)
                    }
                    Width::Pair => {
                        // All ones where the pose's tool is `i`: `x` there, +0 elsewhere,
                        // the bits the one-pose `select` gives.
                        let i = b.ins().iconst(types::I64, i64::from(i));
                        let i = b.ins().splat(types::I64X2, i);
                        let c = b.ins().icmp(IntCC::Equal, tool, i);
                        let mask = b.ins().bitcast(types::F64X2, vector_cast(), c);
                        b.ins().band(x, mask)
                    }
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn sincos_is_sin_and_cos_bit_for_bit() {
        // The generated code takes both from one `sincos` call; the interpreter calls `sin` and
        // `cos` separately. They must agree exactly, tiny and huge arguments included.
        let mut x = 1e-300f64;
        let mut checked = 0;
        while x < 1e22 {
            for v in [x, -x, x * 1.37, x * 0.71] {
                let (s, c) = libm::sincos(v);
                assert_eq!(s.to_bits(), libm::sin(v).to_bits(), "sin {v:e}");
                assert_eq!(c.to_bits(), libm::cos(v).to_bits(), "cos {v:e}");
                checked += 1;
            }
            x *= 1.01;
        }
        assert!(checked > 10_000);
    }
}
