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

use std::mem::offset_of;

use cranelift_codegen::ir::condcodes::{FloatCC, IntCC};
use cranelift_codegen::ir::immediates::Ieee64;
use cranelift_codegen::ir::{
    types, AbiParam, BlockArg, ConstantData, InstBuilder, MemFlagsData, StackSlotData,
    StackSlotKind, UserFuncName, Value,
};
use cranelift_codegen::settings::{self, Configurable};
use cranelift_codegen::Context;
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{default_libcall_names, FuncId, Linkage, Module};

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
/// (see `JitModel::call` in `mod.rs`).
pub(super) type RawFn = unsafe extern "C" fn(*const Args);

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
/// function and the machine code it became are appended to it (the `--dump clif` view).
pub(super) fn compile(
    graphs: &[(String, &Graph)],
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
    let mut jb = JITBuilder::with_isa(isa, default_libcall_names());
    jb.symbol(
        SINCOS,
        kin_jit_sincos as extern "C" fn(f64, *mut f64) as *const u8,
    );
    jb.symbol(
        FMOD,
        kin_jit_fmod as extern "C" fn(f64, f64) -> f64 as *const u8,
    );
    let mut module = JITModule::new(jb);

    let result = define_all(&mut module, graphs, &mut dump);
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

fn define_all(
    module: &mut JITModule,
    graphs: &[(String, &Graph)],
    dump: &mut Option<&mut String>,
) -> Result<Vec<FuncId>, JitError> {
    let ptr = module.target_config().pointer_type();
    let mut sincos_sig = module.make_signature();
    sincos_sig.params.push(AbiParam::new(types::F64));
    sincos_sig.params.push(AbiParam::new(ptr));
    let sincos = module
        .declare_function(SINCOS, Linkage::Import, &sincos_sig)
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
    let mut ctx = module.make_context();
    let mut fctx = FunctionBuilderContext::new();
    let mut ids = Vec::with_capacity(graphs.len());
    for (name, graph) in graphs {
        let id = module
            .declare_function(name, Linkage::Local, &sig)
            .map_err(codegen)?;
        ctx.func.signature = sig.clone();
        ctx.func.name = UserFuncName::user(0, id.as_u32());
        let imports = Imports {
            sincos: module.declare_func_in_func(sincos, &mut ctx.func),
            fmod: module.declare_func_in_func(fmod, &mut ctx.func),
        };
        emit_function(
            &mut ctx,
            &mut fctx,
            graph,
            &imports,
            ptr,
            module.target_config(),
        );
        if let Some(d) = dump.as_deref_mut() {
            d.push_str(&format!("; {name}\n{}\n", ctx.func.display()));
        }
        let disasm = dump.is_some();
        ctx.set_disasm(disasm);
        module
            .define_function(id, &mut ctx)
            .map_err(|e| JitError::Codegen {
                message: format!("{name}: {e:?}"),
            })?;
        if let (Some(d), Some(text)) = (
            dump.as_deref_mut(),
            ctx.compiled_code().and_then(|c| c.vcode.as_deref()),
        ) {
            d.push_str(&format!("; {name}: machine code\n{text}\n"));
        }
        module.clear_context(&mut ctx);
        ids.push(id);
    }
    Ok(ids)
}

struct Imports {
    sincos: cranelift_codegen::ir::FuncRef,
    fmod: cranelift_codegen::ir::FuncRef,
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
    let flags = MemFlagsData::trusted();
    // Calls first: the C calling convention saves no float register across a call, so every
    // value live at a call is spilled. At the top only the calls' own inputs and results are.
    let live = graph.live();
    for (i, node) in graph.nodes().iter().enumerate() {
        if live.get(i).copied().unwrap_or(false)
            && matches!(node, Node::Sin(_) | Node::Cos(_) | Node::Fmod(..))
        {
            e.value(&mut b, Id::new(i));
        }
    }
    for &effect in graph.effects() {
        match effect {
            Effect::Eval(value) => {
                e.value(&mut b, value);
            }
            Effect::Store(dst, index, value) => {
                let v = e.value(&mut b, value);
                let base = e.base_ptr(&mut b, dst_field(dst));
                if let (Some(v), Some(base)) = (v, base) {
                    b.ins().store(flags, v, base, elem(index));
                }
            }
            Effect::AddTo(dst, index, value) => {
                let v = e.value(&mut b, value);
                let base = e.base_ptr(&mut b, dst_field(dst));
                if let (Some(v), Some(base)) = (v, base) {
                    let old = b.ins().load(types::F64, flags, base, elem(index));
                    let sum = b.ins().fadd(old, v);
                    b.ins().store(flags, sum, base, elem(index));
                }
            }
            Effect::Pair(dst, index, col, x, y) => {
                let v = e.pair(&mut b, col, x, y);
                let base = e.base_ptr(&mut b, dst_field(dst));
                if let (Some(v), Some(base)) = (v, base) {
                    // The buffer is only 8-byte aligned: a 16-byte store without `aligned`.
                    b.ins()
                        .store(MemFlagsData::new().with_notrap(), v, base, elem(index));
                }
            }
        }
    }
    b.ins().return_(&[]);
    b.seal_all_blocks();
    b.finalize(config);
}

struct Emitter<'g> {
    graph: &'g Graph,
    values: Vec<Option<Value>>,
    /// Pointers loaded from the argument block, by field offset.
    bases: std::collections::HashMap<i32, Value>,
    tool: Option<Value>,
    args: Option<Value>,
    /// Each column entry's two-lane splat, made once and used by every pair of its component.
    splats: std::collections::HashMap<Id, Value>,
    /// Results of `sincos` calls: the slot and offset each is read from.
    slots: std::collections::HashMap<Id, (cranelift_codegen::ir::StackSlot, i32)>,
    lanes: std::collections::HashMap<(Id, Id), Value>,
    ptr: types::Type,
    imports: &'g Imports,
}

impl Emitter<'_> {
    fn base_ptr(&mut self, b: &mut FunctionBuilder, offset: i32) -> Option<Value> {
        if let Some(v) = self.bases.get(&offset) {
            return Some(*v);
        }
        let v = b
            .ins()
            .load(self.ptr, MemFlagsData::trusted(), self.args?, offset);
        self.bases.insert(offset, v);
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

    /// The value of operand `id`. Constants are not kept in registers: each use gets its own
    /// `f64const`, which the backend folds into the instruction as a constant-pool operand
    /// (or a register clear for 0), instead of holding it live (and spilling it) across the
    /// function.
    fn operand(&mut self, b: &mut FunctionBuilder, id: Id) -> Option<Value> {
        if let Some(&(slot, offset)) = self.slots.get(&id) {
            return Some(b.ins().stack_load(self.ptr, types::F64, slot, offset));
        }
        match self.graph.node(id) {
            Node::Const(bits) => Some(b.ins().f64const(Ieee64::with_bits(bits))),
            _ => self.get(id),
        }
    }

    /// Whether `id` needs no emitting: done already, a constant, or a result in a slot.
    fn available(&self, id: Id) -> bool {
        self.get(id).is_some()
            || self.slots.contains_key(&id)
            || matches!(self.graph.node(id), Node::Const(_))
    }

    /// `[col·x, col·y]` as one two-lane product: the same two roundings as two scalar
    /// products. Splats and lane pairs are shared between the six rows of a coefficient pair.
    fn pair(&mut self, b: &mut FunctionBuilder, col: Id, x: Id, y: Id) -> Option<Value> {
        if self.graph.value(col) == Some(0.0) {
            // A register clear, rematerialised at each use like the scalar constants.
            let zero = b
                .func
                .dfg
                .constants
                .insert(ConstantData::from(&[0u8; 16][..]));
            return Some(b.ins().vconst(types::F64X2, zero));
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
                // `splat` then `insertlane`: two instructions, where `scalar_to_vector` first
                // clears the upper lane that `insertlane` overwrites anyway.
                let v = b.ins().splat(types::F64X2, xv);
                let v = b.ins().insertlane(v, yv, 1);
                self.lanes.insert((x, y), v);
                v
            }
        };
        Some(b.ins().fmul(splat, lanes))
    }

    /// Emits `root` and whatever it needs, depth first without recursion (sums over hundreds
    /// of coefficients make deep operand chains).
    fn value(&mut self, b: &mut FunctionBuilder, root: Id) -> Option<Value> {
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
            let v = self.emit(b, id, node)?;
            self.set(id, v);
        }
        self.operand(b, root)
    }

    /// `sin x, cos x` into `slot` (sine at 0, cosine at 8) by one `libm::sincos` call, unless
    /// `x` usually equals a value whose call came earlier ([`Graph::usual`]): then, when the
    /// bits are equal, that call's results are copied, the same numbers the call would give.
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
            let addr = b.ins().stack_addr(self.ptr, slot, 0);
            b.ins().call(self.imports.sincos, &[xv, addr]);
            return Some(());
        };
        let yv = self.value(b, y)?;
        let flags = MemFlagsData::new();
        let (xi, yi) = (
            b.ins().bitcast(types::I64, flags, xv),
            b.ins().bitcast(types::I64, flags, yv),
        );
        let same = b.ins().icmp(IntCC::Equal, xi, yi);
        let (copy, call, join) = (b.create_block(), b.create_block(), b.create_block());
        b.ins().brif(same, copy, &[], call, &[]);
        b.switch_to_block(copy);
        for offset in [0, 8] {
            let v = b.ins().stack_load(self.ptr, types::F64, from, offset);
            b.ins().stack_store(self.ptr, v, slot, offset);
        }
        b.ins().jump(join, &[]);
        b.switch_to_block(call);
        let addr = b.ins().stack_addr(self.ptr, slot, 0);
        b.ins().call(self.imports.sincos, &[xv, addr]);
        b.ins().jump(join, &[]);
        b.switch_to_block(join);
        Some(())
    }

    fn emit(&mut self, b: &mut FunctionBuilder, id: Id, node: Node) -> Option<Value> {
        let flags = MemFlagsData::trusted();
        let mut ops = [None; 4];
        for (slot, op) in ops.iter_mut().zip(super::graph::operands(node)) {
            *slot = Some(self.operand(b, op)?);
        }
        let [p, q, r, t] = ops;
        Some(match node {
            Node::Const(bits) => b.ins().f64const(Ieee64::with_bits(bits)),
            Node::Load(Src::Time, _) => {
                b.ins()
                    .load(types::F64, flags, self.args?, field(Src::Time))
            }
            Node::Load(src, i) => {
                let base = self.base_ptr(b, field(src))?;
                b.ins().load(types::F64, flags, base, elem(i))
            }
            Node::Add(..) => b.ins().fadd(p?, q?),
            Node::Sub(..) => b.ins().fsub(p?, q?),
            Node::Mul(..) => b.ins().fmul(p?, q?),
            Node::Div(..) => b.ins().fdiv(p?, q?),
            Node::PosPart(_) => {
                let a = p?;
                let abs = b.ins().fabs(a);
                let twice = b.ins().fadd(a, abs);
                let half = b.ins().f64const(0.5);
                b.ins().fmul(twice, half)
            }
            Node::Neg(_) => b.ins().fneg(p?),
            Node::Floor(_) => b.ins().floor(p?),
            Node::Sin(x) | Node::Cos(x) => {
                // One call gives both, into a stack slot of its own. The results stay there
                // and are loaded at each use: every float register dies at the next call, so
                // holding them in registers would only add a spill.
                let slot = b.create_sized_stack_slot(StackSlotData::new(
                    StackSlotKind::ExplicitSlot,
                    16,
                    3,
                ));
                self.sincos(b, x, p?, slot)?;
                for (node, offset) in [(Node::Sin(x), 0), (Node::Cos(x), 8)] {
                    if let Some(n) = self.graph.find(&node) {
                        self.slots.insert(n, (slot, offset));
                    }
                }
                let offset = if matches!(node, Node::Sin(_)) { 0 } else { 8 };
                self.slots.insert(id, (slot, offset));
                b.ins().stack_load(self.ptr, types::F64, slot, offset)
            }
            Node::Fmod(..) => {
                // `fmod(a, m)` is `a` itself, exactly, when `|a| < |m|` (a continuous axis
                // within its first turn): the call only where it is not. A NaN fails the
                // comparison and takes the call, as it would without the test.
                let (a, m) = (p?, q?);
                let (call, join) = (b.create_block(), b.create_block());
                let result = b.append_block_param(join, types::F64);
                let (abs_a, abs_m) = (b.ins().fabs(a), b.ins().fabs(m));
                let inside = b.ins().fcmp(FloatCC::LessThan, abs_a, abs_m);
                b.ins().brif(inside, join, &[BlockArg::Value(a)], call, &[]);
                b.switch_to_block(call);
                let called = b.ins().call(self.imports.fmod, &[a, m]);
                let r = b.inst_results(called).first().copied()?;
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
                b.ins().select(c, r?, t?)
            }
            Node::IfTool(i, _) => {
                let tool = match self.tool {
                    Some(t) => t,
                    None => {
                        let t = b.ins().load(
                            types::I64,
                            flags,
                            self.args?,
                            offset_of!(Args, tool) as i32,
                        );
                        self.tool = Some(t);
                        t
                    }
                };
                let c = b.ins().icmp_imm_u(IntCC::Equal, tool, i64::from(i));
                let zero = b.ins().f64const(0.0);
                b.ins().select(c, p?, zero)
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
