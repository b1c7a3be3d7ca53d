;; The fit's hot loops (layout.js, fit): the decoder's hidden layer for many
;; voxels at once, 4 units per instruction (WebAssembly SIMD), forward and
;; back. With n = (i * y + j) * z + k a voxel of an (x, y, z) grid and
;;   pre[n, h] = (xy[i, j, h] + xz[i, k, h]) + (yz[j, k, h] + bias[h]),
;; decode:   out[n] = sum over h of max(0, pre[n, h]) * w2[h], where live[n] != 0
;;           (everywhere with $all), in four lanes (lane l: h = l, l + 4, ...,
;;           in order), then (lane 0 + lane 1) + (lane 2 + lane 3): the order
;;           runtime/layout.py's fit adds in, so that both make the same floats;
;; backward: for every n with g[n] != 0 and every h with pre[n, h] > 0, adds
;;           g[n] * w2[h] to dxy[i, j, h], dxz[i, k, h] and dyz[j, k, h].
;; The terms and their gradients are f32 rows of $stride units (a multiple of
;; 4, zero-padded); every pointer is a byte offset into the imported memory.
;; Built into decode-wasm.js by tools/build_wasm.py.
(module
  (import "env" "memory" (memory 1))
  (func (export "decode")
        (param $xy i32) (param $xz i32) (param $yz i32) (param $bias i32) (param $w2 i32)
        (param $live i32) (param $all i32) (param $out i32)
        (param $x i32) (param $y i32) (param $z i32) (param $stride i32)
    (local $i i32) (local $j i32) (local $k i32) (local $n i32) (local $h i32) (local $row i32)
    (local $a i32) (local $b i32) (local $e i32) (local $sum v128) (local $v v128)
    (local.set $row (i32.shl (local.get $stride) (i32.const 2))) ;; bytes per row of terms
    (local.set $n (i32.const 0)) ;; the voxel, (i * y + j) * z + k
    (local.set $i (i32.const 0))
    (block $i_done (loop $i_next
      (br_if $i_done (i32.ge_u (local.get $i) (local.get $x)))
      (local.set $j (i32.const 0))
      (block $j_done (loop $j_next
        (br_if $j_done (i32.ge_u (local.get $j) (local.get $y)))
        (local.set $k (i32.const 0))
        (block $k_done (loop $k_next
          (br_if $k_done (i32.ge_u (local.get $k) (local.get $z)))
          (if (i32.or (local.get $all) (i32.load8_u (i32.add (local.get $live) (local.get $n))))
            (then
              (local.set $a (i32.add (local.get $xy)
                (i32.mul (i32.add (i32.mul (local.get $i) (local.get $y)) (local.get $j)) (local.get $row))))
              (local.set $b (i32.add (local.get $xz)
                (i32.mul (i32.add (i32.mul (local.get $i) (local.get $z)) (local.get $k)) (local.get $row))))
              (local.set $e (i32.add (local.get $yz)
                (i32.mul (i32.add (i32.mul (local.get $j) (local.get $z)) (local.get $k)) (local.get $row))))
              (local.set $sum (f32x4.splat (f32.const 0)))
              (local.set $h (i32.const 0))
              (block $h_done (loop $h_next ;; 4 units (16 bytes) at a time
                (br_if $h_done (i32.ge_u (local.get $h) (local.get $row)))
                (local.set $v (f32x4.add
                  (f32x4.add (v128.load (i32.add (local.get $a) (local.get $h)))
                             (v128.load (i32.add (local.get $b) (local.get $h))))
                  (f32x4.add (v128.load (i32.add (local.get $e) (local.get $h)))
                             (v128.load (i32.add (local.get $bias) (local.get $h))))))
                (local.set $sum (f32x4.add (local.get $sum)
                  (f32x4.mul (f32x4.max (local.get $v) (f32x4.splat (f32.const 0)))
                             (v128.load (i32.add (local.get $w2) (local.get $h))))))
                (local.set $h (i32.add (local.get $h) (i32.const 16)))
                (br $h_next)))
              (f32.store (i32.add (local.get $out) (i32.shl (local.get $n) (i32.const 2)))
                (f32.add (f32.add (f32x4.extract_lane 0 (local.get $sum)) (f32x4.extract_lane 1 (local.get $sum)))
                         (f32.add (f32x4.extract_lane 2 (local.get $sum)) (f32x4.extract_lane 3 (local.get $sum)))))))
          (local.set $n (i32.add (local.get $n) (i32.const 1)))
          (local.set $k (i32.add (local.get $k) (i32.const 1)))
          (br $k_next)))
        (local.set $j (i32.add (local.get $j) (i32.const 1)))
        (br $j_next)))
      (local.set $i (i32.add (local.get $i) (i32.const 1)))
      (br $i_next))))
  (func (export "backward")
        (param $xy i32) (param $xz i32) (param $yz i32) (param $bias i32) (param $w2 i32) (param $g i32)
        (param $dxy i32) (param $dxz i32) (param $dyz i32)
        (param $x i32) (param $y i32) (param $z i32) (param $stride i32)
    (local $i i32) (local $j i32) (local $k i32) (local $n i32) (local $h i32) (local $row i32)
    (local $a i32) (local $b i32) (local $e i32) (local $gn f32) (local $add v128)
    (local.set $row (i32.shl (local.get $stride) (i32.const 2)))
    (local.set $n (i32.const 0))
    (local.set $i (i32.const 0))
    (block $i_done (loop $i_next
      (br_if $i_done (i32.ge_u (local.get $i) (local.get $x)))
      (local.set $j (i32.const 0))
      (block $j_done (loop $j_next
        (br_if $j_done (i32.ge_u (local.get $j) (local.get $y)))
        (local.set $k (i32.const 0))
        (block $k_done (loop $k_next
          (br_if $k_done (i32.ge_u (local.get $k) (local.get $z)))
          (local.set $gn (f32.load (i32.add (local.get $g) (i32.shl (local.get $n) (i32.const 2)))))
          (if (f32.ne (local.get $gn) (f32.const 0))
            (then
              (local.set $a (i32.mul (i32.add (i32.mul (local.get $i) (local.get $y)) (local.get $j)) (local.get $row)))
              (local.set $b (i32.mul (i32.add (i32.mul (local.get $i) (local.get $z)) (local.get $k)) (local.get $row)))
              (local.set $e (i32.mul (i32.add (i32.mul (local.get $j) (local.get $z)) (local.get $k)) (local.get $row)))
              (local.set $h (i32.const 0))
              (block $h_done (loop $h_next
                (br_if $h_done (i32.ge_u (local.get $h) (local.get $row)))
                ;; g * w2 where pre > 0, else 0
                (local.set $add (v128.and
                  (f32x4.mul (f32x4.splat (local.get $gn)) (v128.load (i32.add (local.get $w2) (local.get $h))))
                  (f32x4.gt
                    (f32x4.add
                      (f32x4.add (v128.load (i32.add (i32.add (local.get $xy) (local.get $a)) (local.get $h)))
                                 (v128.load (i32.add (i32.add (local.get $xz) (local.get $b)) (local.get $h))))
                      (f32x4.add (v128.load (i32.add (i32.add (local.get $yz) (local.get $e)) (local.get $h)))
                                 (v128.load (i32.add (local.get $bias) (local.get $h)))))
                    (f32x4.splat (f32.const 0)))))
                (v128.store (i32.add (i32.add (local.get $dxy) (local.get $a)) (local.get $h))
                  (f32x4.add (v128.load (i32.add (i32.add (local.get $dxy) (local.get $a)) (local.get $h))) (local.get $add)))
                (v128.store (i32.add (i32.add (local.get $dxz) (local.get $b)) (local.get $h))
                  (f32x4.add (v128.load (i32.add (i32.add (local.get $dxz) (local.get $b)) (local.get $h))) (local.get $add)))
                (v128.store (i32.add (i32.add (local.get $dyz) (local.get $e)) (local.get $h))
                  (f32x4.add (v128.load (i32.add (i32.add (local.get $dyz) (local.get $e)) (local.get $h))) (local.get $add)))
                (local.set $h (i32.add (local.get $h) (i32.const 16)))
                (br $h_next)))))
          (local.set $n (i32.add (local.get $n) (i32.const 1)))
          (local.set $k (i32.add (local.get $k) (i32.const 1)))
          (br $k_next)))
        (local.set $j (i32.add (local.get $j) (i32.const 1)))
        (br $j_next)))
      (local.set $i (i32.add (local.get $i) (i32.const 1)))
      (br $i_next))))
)
